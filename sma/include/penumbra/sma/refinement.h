#pragma once
// Refinement criteria (founding paper §4): which displayed leaves to split,
// so that samples go where the lighting changes fast.
//
// The metric (paper eq. 1). For points x_1..x_n with tone-mapped luminances
// L(x_i), normalised by the view's largest tone-mapped luminance L_max:
//
//   S = sqrt( sum_{i<j} (L(x_i) - L(x_j))^2 / ((n^2 div 4) * L_max^2) )
//
// L is Drago 2003 (common/tonemap.h, as the client displays it) applied to
// the luminance of the vertex's *untextured* radiance Le + Kd * E / pi: the
// lighting the mesh must carry. Texture detail is the client's job (it
// modulates the texture by interpolated irradiance), so texture variation
// between vertices must not look like a shadow edge.
//
// Noise. Samples are Monte Carlo estimates; two neighbours may differ by
// noise alone, and the plain metric then splits where nothing is there (on
// a path tracer's samples far more than on the paper's Radiance, whose
// irradiance cache smooths them). With noiseZ > 0 every pairwise difference
// is first reduced by noiseZ standard errors of that difference -- each
// sample's error comes from the renderer, carried through the tone mapping
// -- and only what noise cannot explain counts. noiseZ = 0 is the paper's S.
//
// Criteria:
//  * NLD_OS (object space): every visible leaf with S over its three corners
//    > S_req and covering >= minPixels pixels is split; a leaf covering more
//    than largeFraction of the image is split whatever its S (a shadow may
//    cross it without touching a vertex, paper Fig. 2). Children become
//    candidates once shaded. Ends when no leaf qualifies and none of its
//    splits awaits samples.
//    Interior probes: corners that agree say nothing about a leaf's inside.
//    A leaf covering more than probeFraction of the image is split, whatever
//    its S, when it is a root (never looked inside), when its parent's split
//    found a midpoint off the line of its edge by more than S_req
//    (MidpointDeviation), or when none of its corners is in sight
//    (VertexInSight): corners hidden behind furniture or off screen stand
//    for the surface around them, not for the part the camera sees between
//    them (a wall's strip between a sofa and a painting, whose corners are
//    behind both).
//  * NLD_IS (image space): quadrants of the image, recursively; S over each
//    quadrant's four corners (luminance interpolated from the displayed
//    leaves); of each quadrant's four sub-quadrants the one with the largest
//    S has the leaf at its centre split, if S > S_req and the leaf covers
//    >= minPixels. Level by level: a level is visited once the previous
//    level's splits are shaded and displayed. Ends at pixel-sized quadrants
//    or when pixelFraction of the image's pixels have been requested.
//  * RND: leaves under random pixels are split (covering >= minPixels), R
//    points per step; ends after pixelFraction of the pixels have been drawn.
//  * NLD_OS_RND: NLD_OS, then a random pass (pixelFraction / 4 of the
//    pixels, drawn in proportion to coverage among leaves NLD_OS left alone),
//    then NLD_OS again on what the random pass found -- the paper's proposed
//    future work, to catch features that touch no vertex.
// Every criterion hands its choices to Hierarchy::Refine, which splits 1 -> 4
// and propagates to neighbours (§4.2); at most `batch` (the paper's R)
// leaves per step, so a new view is taken between steps (§4.1).
//
// Threads: a Refiner belongs to one client session and is used by one thread
// at a time; Select() reads the hierarchy and cache under the SMA's state
// lock held shared by the caller.

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <unordered_map>
#include <vector>

#include "penumbra/common/expected.h"
#include "penumbra/common/refinement_params.h"
#include "penumbra/common/rng.h"
#include "penumbra/common/tonemap.h"
#include "penumbra/sma/hierarchy.h"
#include "penumbra/sma/sample_cache.h"
#include "penumbra/sma/visibility.h"

namespace penumbra::sma {

// The criteria's names and the parameters are shared with clients
// (common/refinement_params.h); the hierarchy's options follow from them.
using penumbra::Criterion;
using penumbra::CriterionName;
using penumbra::ParseCriterion;
using penumbra::RefinementParams;

/// The propagation options of Hierarchy::Refine that `params` imply.
RefineOptions ToRefineOptions(const RefinementParams& params);

/// The metric S (eq. 1) over tone-mapped luminances `l`, normalised by `lMax`.
float NormalizedLuminanceDifference(std::span<const float> l, float lMax);

/// S with each difference |l_i - l_j| reduced (not below 0) by
/// z * sqrt(sigma_i^2 + sigma_j^2), sigma being the standard errors of `l`.
/// z = 0 gives NormalizedLuminanceDifference.
float NoiseAwareLuminanceDifference(std::span<const float> l, std::span<const float> sigma, float z, float lMax);

class VertexLuminance;

/// Whether the camera of `hits` sees vertex `v` (static scene part): it
/// projects into the image and at its pixel or one of the eight around it
/// nothing is nearer than it by more than 1 % of its distance and two
/// pixels' size. Vertices of moving objects count as seen (the hierarchy
/// holds them at rest, the view saw them posed).
bool VertexInSight(const Hierarchy& h, const HitBuffer& hits, const PinholeCamera& camera, VertexId v);

/// How far the midpoints node `n`'s split added stand from the linear
/// interpolation of their edges' ends (tone-mapped luminance, each
/// difference reduced by z standard errors of itself, not below 0), over
/// lMax: the largest over the split's shaded midpoints; 0 for a leaf or
/// while the samples are missing.
float MidpointDeviation(const SampleCache& cache, const Node& n, VertexLuminance& lum, float z, float lMax);

/// Tone-mapped luminance of vertices, memoised, for one view's statistics.
class VertexLuminance {
 public:
  VertexLuminance(const Hierarchy& hierarchy, const SampleCache& cache, const ViewLuminance& view,
                  const DragoParams& params);
  /// L(v) in [0, 1]; 0 for an unshaded vertex.
  float operator()(VertexId v) { return Get(v).luminance; }
  /// Standard error of L(v), from the renderer's error carried through the
  /// tone mapping.
  float Sigma(VertexId v) { return Get(v).sigma; }

  /// The statistics of the untextured radiance of every corner of `nodes`.
  static ViewLuminance Measure(const Hierarchy& hierarchy, const SampleCache& cache, std::span<const NodeId> nodes);
  /// Le + Kd E / pi of a shaded vertex.
  static Rgb UntexturedRadiance(const Hierarchy& hierarchy, const SampleCache& cache, VertexId v);

 private:
  struct Value {
    float luminance = 0.0f;
    float sigma = 0.0f;
  };
  const Value& Get(VertexId v);

  const Hierarchy& hierarchy_;
  const SampleCache& cache_;
  ViewLuminance view_;
  DragoParams params_;
  std::unordered_map<VertexId, Value> memo_;
};

/// One client view's refinement. The session's RefinementDriver makes a new
/// one for every new view (a step still running keeps the old one, so its
/// result is recognised as stale); Select() once per step with the latest
/// visibility.
class Refiner {
 public:
  explicit Refiner(RefinementParams params);

  void Reset(const RefinementParams& params);
  const RefinementParams& Params() const { return params_; }

  /// Up to `batch` displayed leaves to split now, chosen by the criterion
  /// from `visible` (whose `hits` gave it). Leaves already split in the
  /// hierarchy are never chosen. Empty when nothing qualifies now.
  /// `samplesOutstanding`: earlier splits still await samples (or their
  /// children are not displayed yet), so an empty choice is not final.
  std::vector<NodeId> Select(const Hierarchy& hierarchy, const SampleCache& cache, const HitBuffer& hits,
                             const VisibleSet& visible, const DragoParams& toneMapping, bool samplesOutstanding);

  /// The criterion has nothing more to do for this view: NLD_OS found no
  /// candidate with nothing outstanding; NLD_IS ran out of quadrants or
  /// budget; RND out of points.
  bool Exhausted() const { return exhausted_; }
  /// Samples this refiner's splits asked for (NLD_IS / RND budget).
  void CountRequested(size_t samples) { requested_ += samples; }
  size_t Requested() const { return requested_; }

 private:
  struct Quadrant {
    int x0, y0, x1, y1;  // pixel corners, inclusive
    int level;           // 0: the whole image; children are one level deeper
  };
  std::vector<NodeId> SelectObjectSpace(const Hierarchy& h, const SampleCache& cache, const HitBuffer& hits,
                                        const VisibleSet& visible, VertexLuminance& lum, float lMax, size_t limit);
  std::vector<NodeId> SelectImageSpace(const Hierarchy& h, const SampleCache& cache, const HitBuffer& hits,
                                       const VisibleSet& visible, VertexLuminance& lum, float lMax,
                                       bool samplesOutstanding);
  std::vector<NodeId> SelectRandom(const Hierarchy& h, const SampleCache& cache, const VisibleSet& visible,
                                   size_t points, size_t limit);
  bool Splittable(const Hierarchy& h, const SampleCache& cache, NodeId id, uint32_t coverage) const;

  RefinementParams params_;
  Pcg32 rng_;
  bool exhausted_ = false;
  size_t requested_ = 0;
  size_t pointsDrawn_ = 0;
  // NLD_IS: quadrants still to visit, coarse first.
  std::vector<Quadrant> quadrants_;
  size_t nextQuadrant_ = 0;
  bool quadrantsSeeded_ = false;
  int level_ = 0;  // quadtree level being visited
  // NLD_OS_RND: 0 = first NLD_OS pass, 1 = random pass, 2 = final NLD_OS pass.
  int phase_ = 0;
};

}  // namespace penumbra::sma
