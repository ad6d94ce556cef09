#pragma once
// Visibility computed the slow, obvious way, as an independent reference:
// every pixel centre's ray against every base triangle (Möller–Trumbore in
// double precision), closest hit wins. Only triangles wholly outside the
// pyramid of a 16-pixel tile (by more than a hit's tie margin) are skipped
// for its pixels: the same answers, some 30 times sooner on Sponza.
//
// BruteForceVisibleTriangles names what is seen as the SMA's hierarchy does:
// by root id, base triangle t for its front side and, in a two-sided scene,
// triangles.size() + t for its back (Hierarchy: "Sides").

#include <cstdint>
#include <set>
#include <vector>

#include "penumbra/common/camera.h"
#include "penumbra/common/scene.h"

namespace penumbra::testing {

struct BruteVisibility {  // root ids, see above
  std::set<uint32_t> certain;  // hit by a pixel whose hit is clear of every triangle edge
  std::set<uint32_t> ties;     // hit only where a hit lies within `tieBary` of an edge (either side may win)
};

/// `tieBary`: a hit whose smallest barycentric is below it, or whose
/// distance is within a relative 1e-5 of another triangle's, is a tie.
BruteVisibility BruteForceVisibleTriangles(const Scene& scene, const CameraView& view, double tieBary = 1e-4);

/// What each pixel centre's ray hits, by the same rules, for image checks.
inline constexpr int64_t kPixelMiss = -1;  // no triangle, not even within tieBary of an edge
inline constexpr int64_t kPixelTie = -2;   // a hit near an edge or between near-equal distances
/// Row-major, row 0 at the top: the base triangle hit (either side), kPixelMiss or kPixelTie.
std::vector<int64_t> BruteForcePixelHits(const Scene& scene, const CameraView& view, double tieBary = 1e-4);

}  // namespace penumbra::testing
