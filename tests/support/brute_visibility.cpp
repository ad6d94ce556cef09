#include "support/brute_visibility.h"

#include <cmath>
#include <limits>
#include <optional>
#include <vector>

namespace penumbra::testing {

namespace {

struct D3 {
  double x, y, z;
};
D3 Sub(D3 a, D3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
D3 Cross(D3 a, D3 b) { return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x}; }
double Dot(D3 a, D3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
D3 ToD3(const Vec3& v) { return {v.x, v.y, v.z}; }

struct Candidate {
  uint32_t triangle;
  double distance;
  double margin;  // smallest barycentric: negative just outside the triangle
};

// One pixel centre's ray: the triangle it certainly hits, if any, and every
// triangle that could win it in float arithmetic.
struct PixelResult {
  std::optional<uint32_t> certain;
  std::vector<uint32_t> contenders;
};

// `asRoots`: name what is hit by the hierarchy's root ids -- a base triangle
// t met from behind (in a two-sided scene) is root triangles.size() + t.
PixelResult ClassifyPixel(const Scene& scene, const D3& origin, const D3& dir, double tieBary, bool asRoots,
                          std::vector<Candidate>& hits) {
  PixelResult result;
  hits.clear();
  for (uint32_t t = 0; t < scene.triangles.size(); ++t) {
    const D3 p0 = ToD3(scene.Position(t, 0)), p1 = ToD3(scene.Position(t, 1)), p2 = ToD3(scene.Position(t, 2));
    const D3 e1 = Sub(p1, p0), e2 = Sub(p2, p0);
    const D3 p = Cross(dir, e2);
    const double det = Dot(e1, p);
    if (std::abs(det) < 1e-14) continue;
    const D3 s = Sub(origin, p0);
    const double u = Dot(s, p) / det;
    const D3 q = Cross(s, e1);
    const double v = Dot(dir, q) / det;
    const double dist = Dot(e2, q) / det;
    const double margin = std::min({u, v, 1.0 - u - v});
    if (margin < -tieBary || dist <= 1e-6) continue;
    // det = (e1 x e2) . -dir: negative when the ray travels along the normal.
    const bool back = det < 0.0;
    const uint32_t id = asRoots && back && scene.twoSided ? uint32_t(scene.triangles.size()) + t : t;
    hits.push_back(Candidate{id, dist, margin});
  }
  if (hits.empty()) return result;
  const Candidate* nearest = &hits[0];
  for (const Candidate& c : hits)
    if (c.distance < nearest->distance) nearest = &c;
  // Every triangle hit at (nearly) the nearest distance, and every
  // near-edge hit in front of the nearest clear one, could win in float.
  const Candidate* clear = nullptr;
  for (const Candidate& c : hits)
    if (c.margin >= tieBary && (!clear || c.distance < clear->distance)) clear = &c;
  for (const Candidate& c : hits) {
    const bool atNearest = c.distance <= nearest->distance * (1.0 + 1e-5);
    const bool beforeClear = clear && c.distance <= clear->distance * (1.0 + 1e-5);
    if (atNearest || beforeClear) result.contenders.push_back(c.triangle);
  }
  if (result.contenders.size() == 1 && nearest->margin >= tieBary) result.certain = nearest->triangle;
  return result;
}

}  // namespace

namespace {

// Classifies the ray through every pixel centre, row by row; `use(x, y, pixel)`.
template <typename Use>
void ForEachPixel(const Scene& scene, const CameraView& view, double tieBary, bool asRoots, Use&& use) {
  const PinholeCamera camera(view);
  const D3 origin = ToD3(camera.Origin());
  std::vector<Candidate> hits;
  for (int y = 0; y < view.height; ++y) {
    for (int x = 0; x < view.width; ++x) {
      const D3 dir = ToD3(camera.DirectionThrough(float(x) + 0.5f, float(y) + 0.5f));
      use(x, y, ClassifyPixel(scene, origin, dir, tieBary, asRoots, hits));
    }
  }
}

}  // namespace

BruteVisibility BruteForceVisibleTriangles(const Scene& scene, const CameraView& view, double tieBary) {
  BruteVisibility out;
  ForEachPixel(scene, view, tieBary, /*asRoots=*/true, [&](int, int, const PixelResult& pixel) {
    if (pixel.certain)
      out.certain.insert(*pixel.certain);
    else
      out.ties.insert(pixel.contenders.begin(), pixel.contenders.end());
  });
  for (uint32_t t : out.certain) out.ties.erase(t);
  return out;
}

std::vector<int64_t> BruteForcePixelHits(const Scene& scene, const CameraView& view, double tieBary) {
  std::vector<int64_t> out(size_t(view.width) * size_t(view.height), kPixelMiss);
  ForEachPixel(scene, view, tieBary, /*asRoots=*/false, [&](int x, int y, const PixelResult& pixel) {
    int64_t& result = out[size_t(y) * size_t(view.width) + size_t(x)];
    if (pixel.certain)
      result = *pixel.certain;
    else if (!pixel.contenders.empty())
      result = kPixelTie;
  });
  return out;
}

}  // namespace penumbra::testing
