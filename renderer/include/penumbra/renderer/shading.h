#pragma once
// Shading of one surface sample by path tracing (Lambertian surfaces).
//
// Given a point x on base triangle `triangle`, with normal n, the shader
// estimates the irradiance
//     E(x) = integral over the hemisphere of n of L_in(x, w) cos(theta) dw
// and the radiance leaving x toward the n side,
//     L_out(x) = L_e(x) + albedo(x) / pi * E(x),
// where L_e is the emission of the triangle's material if n faces the same
// way as its front face (emitters emit from their front face only) and
// albedo(x) is the material's Kd times its texture at x.
//
// Incoming radiance comes from:
//  * area lights (emissive triangles): next-event estimation, picking a light
//    triangle in proportion to its power and a point uniformly on it, combined
//    with cosine-sampled directions by multiple importance sampling (power
//    heuristic);
//  * the sun: a disc of angular diameter d, sampled uniformly over its cone
//    (so its shadows have penumbrae); never reached by cosine sampling;
//  * the sky: radiance of escaping cosine-sampled directions;
//  * every other surface: diffuse interreflection, path length bounded by
//    `maxBounces`, with Russian roulette from `russianRouletteDepth` on.
// Every surface reflects on both sides with its material's albedo.
//
// Geometry. Directions that n admits but that point below the plane of the
// sample's own triangle (n is a smoothed vertex normal and may lean away from
// the face) are blocked by that surface and bring nothing. Path vertices
// after the sample are shaded with their triangle's geometric normal, turned
// toward the side the path arrived from. Rays leave a surface from an origin
// moved off it along that normal, and, for the sample itself, slightly into
// its triangle: samples sit on vertices and edges, where a neighbouring
// triangle (a wall meeting a floor) passes through the exact point.
//
// Buried samples. Real models let surfaces run into each other: a stair
// riser's corners sit inside the tread slabs, a skirting board's inside the
// wall, a ceiling's edge inside the cornice. Shaded where it is, such a
// sample sees only the inside of a solid or of a thin cavity and reads
// black, and since all its triangle's corners may, no refinement criterion
// would ever look inside the triangle. Two tests, on the way from the
// triangle's centroid to the sample:
//  * inside a solid: the way enters a solid (meets a front face) and, from
//    the sample, nearly no direction sees a front face (nor, under a sky or
//    sun, the open sky). The sample is shaded where its surface emerges:
//    just before that front face, on the line from the centroid.
//  * enclosed, whatever the facing (real models wind solids any way, and a
//    wall and the board laid over it leave a cavity whose inside faces are
//    front faces): at least 15 of 16 probe directions meet a surface within
//    an eighth of the way to the centroid -- far nearer than the surface the
//    sample stands for extends. The sample is shaded at the nearest point on
//    the way to the centroid that sees past that way's length (at least 2 of
//    16 probes go further): just past a surface the way crosses, or 1/16,
//    1/8, 1/4, 1/2 or all of the way. If there is none, where it is.
// A crease (a wall meeting a floor: half the directions open) is neither,
// and is shaded where it is. Both are counted as buried samples.
//
// Path length. Segment 0 leaves the sample; a path has at most
// `maxBounces` + 1 segments. The lights are sampled from the start of every
// segment, a light sample counting as that segment, so maxBounces = 0 is
// direct light only. The default cap (64 bounces) is far beyond where
// Russian roulette ends paths in any real scene, so the default estimate is
// unbiased to within its noise (a truncated path depth darkens interiors by
// the albedo series it cuts off: 4 bounces were 3.6 % dark on the Cornell box).
// From segment `russianRouletteDepth` on, a path continues with probability
// equal to the largest channel of the albedo it has just met and is
// reweighted by the inverse of that probability, which keeps the estimate
// unbiased.
//
// Movable objects (issue 14). A sample is shaded at one pose of the scene
// (a PosedRayScene): its position and normal are world space at that pose,
// its triangle and barycentrics name the base triangle (whose vertices are
// stored in its object's space), and every ray of its paths meets the
// objects where the pose puts them. Lights are static (Scene::Finalize
// refuses emissive movable objects), so light sampling is the same at every
// pose.
//
// Determinism: sample `sampleId` uses its own random stream, derived from
// (settings.seed, sampleId) only, so the same input gives the same output on
// any thread (with flush-to-zero set, see EnableFlushToZero), in any batch,
// on any renderer process.

#include <atomic>
#include <cstdint>
#include <memory>
#include <span>

#include "penumbra/common/expected.h"
#include "penumbra/common/math.h"
#include "penumbra/common/scene.h"

namespace penumbra {

class RayScene;
class PosedRayScene;

struct ShadingSettings {
  int pathsPerSample = 64;       // --spp: paths averaged per sample, >= 1
  int maxBounces = 64;           // --max-bounces: surfaces a path reflects from after the sample; 0 = direct light only
  int russianRouletteDepth = 3;  // first segment index (from 0) at which paths may be terminated
  int MaxSegments() const { return maxBounces + 1; }
  uint64_t seed = 0;             // global seed mixed into every sample's stream
  /// Adaptive sampling (--max-spp, --target-error). When maxPathsPerSample
  /// exceeds a sample's path count, the shader keeps tracing further rounds
  /// of that many paths while the relative standard error of the luminance
  /// of E (stderr / mean) is above targetRelativeError and the total stays
  /// within maxPathsPerSample: dim, indirectly lit samples -- the noisy ones
  /// -- get more paths, directly lit ones no more. An estimate that is still
  /// exactly black is not known to be accurate (every path finding nothing
  /// does not show there is nothing to find) and also gets more rounds, up
  /// to the cap. 0 = always exactly the path count. The stopping rule looks at the sample's own estimate, which
  /// biases it very slightly toward brighter values; the rounds are small
  /// enough (>= 16 paths) that the bias is far below the noise it removes.
  int maxPathsPerSample = 0;
  float targetRelativeError = 0.05f;
};

struct ShadeInput {
  uint64_t sampleId = 0;
  Vec3 position;          // world space at the pose it is shaded at, on `triangle`
  Vec3 normal;            // world space, unit: the side of the surface to shade
  uint32_t triangle = 0;  // base triangle (Scene::triangles)
  float b1 = 0.0f;        // barycentrics of `position` on `triangle`
  float b2 = 0.0f;
};

struct ShadeOutput {
  Rgb radiance{0.0f};    // L_out: emitted + reflected, linear RGB
  Rgb irradiance{0.0f};  // E, linear RGB
  /// Standard error of Luminance(irradiance): how far this sample may be
  /// from the true value by noise alone (0 when every path agrees, e.g. an
  /// unoccluded uniform sky). The paths are stratified at their first vertex
  /// (direction, sun, point on the light; Shade's comment), so it comes from
  /// the differences of neighbouring strata, not the paths' plain spread,
  /// which would overstate it.
  float irradianceStdErr = 0.0f;
  uint32_t paths = 0;  // paths averaged (adaptive sampling may trace more than asked)
};

/// How much a move changes a sample's irradiance through the region the
/// move swept (Shader::EstimateChangeThrough). Luminance, like the SMA's
/// tolerances.
struct ChangeEstimate {
  float irradianceChange = 0.0f;  // Luminance(E after - E before), first order (see EstimateChangeThrough)
  /// Standard error of irradianceChange, from the spread of the paths' paired
  /// differences (0 when every path saw the same at both poses).
  float standardError = 0.0f;
  uint32_t paths = 0;
  /// Paths whose direction through the region left the sample's side of its
  /// surface (the others bring no light and count 0).
  uint32_t pathsThroughRegion = 0;
  /// The solid angle the region's directions are drawn from (its boxes'
  /// silhouettes, added up; 0: none is in view): no path's share of the
  /// change exceeds the largest radiance change times this, which is what
  /// bounds a change no path saw (at most 3/n of it at 95 %, by the rule of
  /// three).
  float regionSolidAngle = 0.0f;
};

/// Work done, for statistics and benchmarks.
struct ShadeCounters {
  uint64_t paths = 0;
  uint64_t rays = 0;        // closest-hit and shadow rays together
  uint64_t shadowRays = 0;  // of which shadow (occlusion) rays
  uint64_t buriedSamples = 0;  // samples shaded where their surface emerges from geometry burying them

  ShadeCounters& operator+=(const ShadeCounters& other) {
    paths += other.paths;
    rays += other.rays;
    shadowRays += other.shadowRays;
    buriedSamples += other.buriedSamples;
    return *this;
  }
};

/// Checks one input against the scene at `pose`: finite fields, unit normal
/// (within 1e-2), triangle in range, barycentrics in the triangle (within
/// 1e-3), and the position within 1e-4 times the scene's bounding-box
/// diagonal (or 1e-6 times the point's largest coordinate, for an object
/// moved far out) of the triangle's world point at those barycentrics
/// (WorldPointAt). The message names the field and its value. `pose` must
/// have one transform per movable object.
Status ValidateShadeInput(const Scene& scene, const ScenePose& pose, const ShadeInput& input);
/// The same at the scene's initial pose.
Status ValidateShadeInput(const Scene& scene, const ShadeInput& input);

class Shader {
 public:
  /// `scene` and `rays` must outlive the shader. Precomputes per-triangle
  /// data and the light-selection distribution.
  Shader(const Scene& scene, const RayScene& rays, ShadingSettings settings);
  ~Shader();
  Shader(Shader&&) noexcept;
  Shader(const Shader&) = delete;
  Shader& operator=(const Shader&) = delete;

  /// Shades one sample at the pose `at` (from this shader's RayScene) with
  /// `paths` paths (the settings' count when 0), or more under adaptive
  /// sampling (ShadingSettings::maxPathsPerSample). Input must have passed
  /// ValidateShadeInput at that pose. Adds the work done to `counters` when
  /// it is not null. Thread-safe; deterministic.
  /// When `cancel` is set (it is looked at every few dozen paths, so that a
  /// sample of thousands of paths does not hold up a shutdown), the sample
  /// is abandoned: the result is meaningless and must be dropped.
  ShadeOutput Shade(const PosedRayScene& at, const ShadeInput& input, int paths, ShadeCounters* counters,
                    const std::atomic<bool>* cancel = nullptr) const;
  /// The same at the scene's initial pose.
  ShadeOutput Shade(const ShadeInput& input, int paths, ShadeCounters* counters,
                    const std::atomic<bool>* cancel = nullptr) const;

  /// Estimates the change of a static sample's irradiance from pose `before`
  /// to pose `after` (both from this shader's RayScene) that a move sweeping
  /// `region` -- boxes, world space, that hold the moving object at both
  /// poses (its bounds at each, or the SMA's motion volume) -- causes
  /// at first order, without shading the sample again (issue 14,
  /// docs/moving-objects.md "A test instead of a bound"):
  ///     dE = dE_sun + integral over directions w through the region's
  ///          boxes of (L_after(x, w) - L_before(x, w)) cos dw,
  /// where L is everything arriving along w -- an area light's emission, the
  /// sky, reflected light -- and dE_sun the change of the sun's direct light
  /// (a direction never finds the sun). Each of `paths` paired samples takes
  /// one direction w uniform in solid angle over the silhouettes of the
  /// region's boxes (the faces the sample sees, as spherical triangles; from
  /// inside a box, the hemisphere) -- every path where the change can be,
  /// instead of the few a hemisphere's paths would send there --, one point
  /// on the area lights whose shadow ray is tested only if it heads for a
  /// box (the two combined by the balance heuristic: light sampling finds a
  /// small light behind the object, silhouette sampling a thin sliver of a
  /// large one that a penumbra moves across), and one direction in the sun's
  /// cone; each is
  /// traced at both poses from the same random state (common random
  /// numbers): what meets nothing that moved is identical at both and
  /// contributes exactly 0. The lights', sun's and silhouettes' numbers are
  /// stratified over the paired samples. Not counted:
  /// reflected light whose first segment leaves outside the region and meets
  /// the object's effect later (a shadow the object casts elsewhere lighting
  /// the sample less -- second order). The sample is shaded from where
  /// `before` puts it (a static sample: the same at both). Thread-safe;
  /// deterministic in (seed, sampleId). `cancel` as for Shade.
  ChangeEstimate EstimateChangeThrough(const PosedRayScene& before, const PosedRayScene& after,
                                       const ShadeInput& input, std::span<const Bounds3> region, int paths,
                                       ShadeCounters* counters, const std::atomic<bool>* cancel = nullptr) const;

  const ShadingSettings& Settings() const;
  const Scene& GetScene() const;
  const RayScene& GetRays() const;

 private:
  struct Impl;  // the path tracer and its tables (shading.cpp)
  std::unique_ptr<const Impl> impl_;
};

}  // namespace penumbra
