#pragma once
// Motion volumes and move invalidation (issue 14; Loscos & Drettakis 1997,
// "Interactive high-quality soft shadows in scenes with moving objects",
// §3.2 and §6).
//
// When a movable object moves, only cached samples whose radiance the move
// may change need re-shading. The paper bounds the changed region by a
// motion volume: the bounding volume of the object's old and new places (or
// the two places separately when they barely overlap, its §6). Its
// discontinuity mesh then needs only the shafts from the light through that
// volume. A path tracer has no discontinuity mesh, so here the question is
// asked per static vertex instead: "could the move change the irradiance at
// this point by more than the sample's own noise?", in three parts:
//
//  * Direct light, exactly. A light reaches p through the motion volume only
//    if the volume meets the shaft between p and the light: for an area
//    light (an emissive triangle T, emitting from its front face) the convex
//    hull of p and T, tested exactly by separating axes (box against
//    tetrahedron); for the sun, the cone from p towards it (half-angle = its
//    angular radius). The change is then at most the light's radiance times
//    the smaller of the light's and the volume's solid angles. The sky fills
//    every direction, so every direction through the volume above p's
//    tangent plane is in its "shaft": it is bounded like indirect light, by
//    its largest radiance times the volume's solid angle.
//  * Indirect light, a conservative bound: the volume can block or reflect
//    towards p at most `indirectRadiance` (a bound on the radiance of any
//    non-emissive surface) over its projected solid angle (the box's exact
//    cosine-weighted solid angle; its bounding sphere's as a cheap first
//    bound). This is the first-order
//    change (light arriving through the volume); light reflected at other
//    surfaces after they changed (the new shadow on the floor lighting the
//    ceiling a little less) is a higher-order change, down by one more
//    albedo and one more solid angle, and is not bounded here -- the paper
//    ignores indirect light entirely.
//  * A vertex whose tangent plane has the whole volume behind it sees none of
//    it: it is kept at once (the cheap first reject).
//
// Units: everything is compared in luminance of irradiance E at the vertex.
// Reflected radiance is albedo/pi * E, and both the change bound and the
// tolerance (below) scale with albedo/pi, so the albedo cancels: the test
// needs only what the cache already holds per sample, Luminance(irradiance)
// and its standard error. (A black surface, albedo 0, never changes; it is
// invalidated like any other -- harmless, and rare.)
//
// Tolerance, in terms of the samples' own noise (docs/moving-objects.md):
//     tau = max(noiseZ * irradianceStdErr, relativeFloor * E, absoluteFloor)
// A vertex is invalidated when its change bound exceeds tau. With noiseZ = 1
// a kept sample is off by at most its own standard error on top of its noise
// -- the move hides in the noise the sample already shows. The relative
// floor (1 %) keeps converged, nearly noise-free samples from being
// invalidated by every faint bound: 1 % of a surface's brightness is below
// what a display shows.
//
// Threads: a MoveInvalidator is immutable after construction; any number of
// threads may call its const functions at once. It copies what it needs from
// the Scene (which need not outlive it). No locks, no sockets, no I/O.

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "penumbra/common/expected.h"
#include "penumbra/common/math.h"
#include "penumbra/common/scene.h"

namespace penumbra::sma {

/// The union box is kept when its volume is at most this times the sum of
/// the two boxes' volumes; see MotionVolumes.
inline constexpr float kDefaultMergeRatio = 1.0f;

/// One or two world-space boxes that contain everything a move changes:
/// where the object was and where it is now.
struct MotionVolume {
  std::array<Bounds3, 2> boxes{};
  uint32_t count = 0;

  std::span<const Bounds3> Boxes() const { return {boxes.data(), count}; }
};

/// The motion volume of a move from `oldWorld` to `newWorld` (the object's
/// world bounds at its two places, WorldBounds()). One box, their union,
/// when that union is at most `mergeRatio` times the two boxes' volumes
/// together; else the two boxes separately (paper §6).
///
/// Why this rule: the work a box causes (vertices in its shafts and solid
/// angle) grows with its size, and two boxes cost two tests per vertex. With
/// ratio 1 a small move (a cube moved by up to ~40 % of its width along a
/// diagonal, or by its full width along an axis, where the union is exactly
/// the two boxes) stays one box, as in the paper's implementation; a larger
/// move, whose union would be mostly empty space, becomes two boxes. Volumes
/// are measured with each side at least 1 % of the box's longest side, so a
/// flat object (a door, a picture) is not treated as having no volume. An
/// empty box (an object with no geometry) contributes nothing; both empty
/// gives count 0.
MotionVolume MotionVolumes(const Bounds3& oldWorld, const Bounds3& newWorld,
                           float mergeRatio = kDefaultMergeRatio);

/// The projected (cosine-weighted) solid angle of the axis-aligned box
/// `center` +- `half` seen from `p` on a surface with unit normal `n`, over
/// p's upper hemisphere: the integral of max(0, cos theta) over the
/// directions from p that meet the box -- the irradiance at p from the box
/// were it a uniform emitter of radiance 1. Exact (each face p sees, clipped
/// to the tangent plane, by Lambert's polygon formula); pi when p is inside
/// the box.
float BoxProjectedSolidAngle(const Vec3& p, const Vec3& n, const Vec3& center, const Vec3& half);

/// How strict the invalidation is (see the file comment). Irradiance units
/// throughout: Luminance(E), the quantity the renderer reports a standard
/// error for.
struct InvalidationParams {
  /// tau's noise term: this many standard errors of the sample's irradiance.
  float noiseZ = 1.0f;
  /// tau's relative floor: this fraction of the sample's irradiance.
  float relativeFloor = 0.01f;
  /// tau's absolute floor (irradiance luminance). 0: a sample that reads
  /// black with no noise is invalidated whenever any bound is positive.
  float absoluteFloor = 0.0f;
  /// Bound on the radiance (luminance) of any non-emissive surface, before
  /// and after the move, including the moving object's own: what the volume
  /// can reflect towards a vertex or block from behind it. < 0: the scene's
  /// MaxEmittedRadiance(), always safe (no surface of albedo <= 1 reflects
  /// more than the brightest light) but loose; the SMA passes the largest
  /// cached non-emissive radiance times a margin (docs/moving-objects.md).
  float indirectRadiance = -1.0f;
  /// The boxes are grown by this (world units) on every side, for rays that
  /// leave surfaces from slightly offset origins. < 0: 1e-4 of the scene's
  /// bounding-box diagonal.
  float padding = -1.0f;

  /// tau for a sample of irradiance luminance `irradiance` and standard
  /// error `stdErr`: the largest of the three terms above.
  float Tolerance(float irradiance, float stdErr) const {
    return std::max({noiseZ * stdErr, relativeFloor * irradiance, absoluteFloor});
  }
};

/// What the invalidator needs of one cached static vertex.
struct VertexSample {
  Vec3 position;               // world space
  Vec3 normal;                 // world space, unit: the side the sample shades
  float irradiance = 0.0f;     // Luminance(irradiance) of the cached sample
  float irradianceStdErr = 0.0f;  // its standard error (ShadedSample::irradianceStdErr)
};

/// Why a vertex was or was not invalidated (tests and diagnostics).
struct InvalidationVerdict {
  bool facing = false;        // some box is in front of the vertex's tangent plane
  bool inLightShaft = false;  // some area light's shaft meets a box
  bool inSunCone = false;     // the sun's cone from the vertex meets a box
  float changeBound = 0.0f;   // upper bound on |delta Luminance(E)|, as far as computed
  float directBound = 0.0f;   // of which area lights and the sun, whose shafts through the volume were tested exactly
  float tolerance = 0.0f;     // tau
  bool invalidate = false;    // changeBound > tolerance
  /// Invalidated by the exact shaft tests alone (directBound > tolerance):
  /// a shadow or a sunlit patch of an area light or the sun moves here. The
  /// rest of the invalidated vertices are invalidated by the solid-angle
  /// bound (indirect light and the sky), usually far above the real change:
  /// an SMA may re-shade them after the direct ones.
  bool DirectlyInvalidated() const { return directBound > tolerance; }
};

/// The invalidated vertices of a move in two classes (ascending indices
/// each): `direct`, whose light from area lights or the sun may change
/// beyond the tolerance (InvalidationVerdict::DirectlyInvalidated), and
/// `indirectOnly`, invalidated only with the solid-angle bound of indirect
/// light and the sky added.
struct InvalidatedSet {
  std::vector<uint32_t> direct;
  std::vector<uint32_t> indirectOnly;
  size_t Size() const { return direct.size() + indirectOnly.size(); }
};

/// The same vertices as parallel spans (structure of arrays): index i of
/// each is vertex i. All four must have the same length.
struct VertexSpans {
  std::span<const Vec3> positions;
  std::span<const Vec3> normals;
  std::span<const float> irradiance;
  std::span<const float> irradianceStdErr;
};

/// The per-move test. Build one per move (cheap: it copies the lights that
/// can see the volume at all), then ask it about every cached static vertex.
class MoveInvalidator {
 public:
  /// At most this many boxes are tested one by one; more (many objects
  /// moving at once) are merged into their union, which is conservative.
  static constexpr size_t kMaxBoxes = 16;

  MoveInvalidator(const Scene& scene, const MotionVolume& volume, const InvalidationParams& params = {});
  /// Several objects moved in one scene epoch (an animation tick): one
  /// volume each. Their changes add up at a vertex, so they must be judged
  /// together, not by one invalidator per object (each change could stay
  /// under the tolerance while their sum does not).
  MoveInvalidator(const Scene& scene, std::span<const MotionVolume> volumes, const InvalidationParams& params = {});

  /// Whether the move may change this vertex's radiance by more than the
  /// tolerance. Thread-safe.
  bool MayChange(const VertexSample& v) const { return Judge(v, /*complete=*/false).invalidate; }
  /// The same decision with its reasons. With `complete` false the
  /// computation stops as soon as the decision is known (changeBound and the
  /// flags may then be partial); with true every term is computed.
  InvalidationVerdict Judge(const VertexSample& v, bool complete = true) const;

  /// Indices (ascending) of the vertices that MayChange, over all of them.
  /// Runs in parallel (TBB) over large spans. An error for spans of unequal
  /// length.
  Expected<std::vector<uint32_t>> InvalidatedVertices(const VertexSpans& vertices) const;
  /// The same vertices split by why (InvalidatedSet). Costs a complete
  /// Judge for each invalidated vertex.
  Expected<InvalidatedSet> ClassifyInvalidated(const VertexSpans& vertices) const;

  /// Area lights kept after the per-move cull (those whose front half-space
  /// the volume reaches), for tests and logs.
  size_t RelevantLightCount() const { return lights_.size(); }
  size_t BoxCount() const { return boxes_.size(); }
  float IndirectRadiance() const { return indirectRadiance_; }

 private:
  struct AreaLight {
    std::array<Vec3, 3> corner;  // world space (lights are static)
    Vec3 normal;                 // unit, front face (the side it emits from)
    float radiance;              // Luminance(emission)
  };
  struct Box {
    Vec3 center;
    Vec3 half;     // half extents, padded
    float radius;  // bounding sphere radius
  };

  std::vector<Box> boxes_;  // at most kMaxBoxes
  std::vector<AreaLight> lights_;
  float lightRadianceSum_ = 0.0f;  // sum of lights_[].radiance: caps the direct term cheaply
  bool hasSun_ = false;
  Vec3 sunDirection_{0.0f};
  float sunTanHalfAngle_ = 0.0f;
  float sunSinHalfAngle_ = 0.0f;
  float sunSolidAngle_ = 0.0f;
  float sunRadiance_ = 0.0f;
  float skyRadiance_ = 0.0f;  // largest luminance of the sky over all directions; 0 without a sky
  float indirectRadiance_ = 0.0f;
  InvalidationParams params_;
};

}  // namespace penumbra::sma
