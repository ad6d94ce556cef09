#include "support/brute_visibility.h"

#include <algorithm>
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

// The scene's triangles in double precision, read once.
struct TriangleD {
  D3 p0, e1, e2;
  double extent;  // the longest edge
};

std::vector<TriangleD> TrianglesOf(const Scene& scene) {
  std::vector<TriangleD> out;
  out.reserve(scene.triangles.size());
  for (uint32_t t = 0; t < scene.triangles.size(); ++t) {
    const D3 p0 = ToD3(scene.Position(t, 0)), p1 = ToD3(scene.Position(t, 1)), p2 = ToD3(scene.Position(t, 2));
    const D3 e1 = Sub(p1, p0), e2 = Sub(p2, p0), e3 = Sub(p2, p1);
    const double extent = std::sqrt(std::max({Dot(e1, e1), Dot(e2, e2), Dot(e3, e3)}));
    out.push_back(TriangleD{p0, e1, e2, extent});
  }
  return out;
}

// `candidates`: the triangles (ascending) that a ray may hit; every other
// one it certainly misses by more than tieBary.
// `asRoots`: name what is hit by the hierarchy's root ids -- a base triangle
// t met from behind (in a two-sided scene) is root triangles.size() + t.
PixelResult ClassifyPixel(const Scene& scene, const std::vector<TriangleD>& triangles,
                          const std::vector<uint32_t>& candidates, const D3& origin, const D3& dir, double tieBary,
                          bool asRoots, std::vector<Candidate>& hits) {
  PixelResult result;
  hits.clear();
  for (const uint32_t t : candidates) {
    const TriangleD& tri = triangles[t];
    const D3 p = Cross(dir, tri.e2);
    const double det = Dot(tri.e1, p);
    if (std::abs(det) < 1e-14) continue;
    const D3 s = Sub(origin, tri.p0);
    const double u = Dot(s, p) / det;
    const D3 q = Cross(s, tri.e1);
    const double v = Dot(dir, q) / det;
    const double dist = Dot(tri.e2, q) / det;
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

constexpr int kTile = 16;  // pixels on a side of the tiles the triangles are culled for

// The triangles that may meet a ray through a pixel centre of the tile
// [x0, x1) x [y0, y1): every triangle not wholly outside one side of the
// pyramid through the tile's outer pixel edges -- half a pixel beyond its
// outermost pixel centres, far more than float error in the corner
// directions -- with each triangle grown by what a hit tieBary outside it
// may lie off it (a corner of the grown triangle is at most 2 tieBary
// edges from the triangle's). Ascending, as the brute-force loop was.
void TileCandidates(const PinholeCamera& camera, const D3& origin, const std::vector<TriangleD>& triangles,
                    int x0, int y0, int x1, int y1, double tieBary, std::vector<uint32_t>& out) {
  out.clear();
  const D3 corner[4] = {ToD3(camera.DirectionThrough(float(x0), float(y0))),
                        ToD3(camera.DirectionThrough(float(x1), float(y0))),
                        ToD3(camera.DirectionThrough(float(x1), float(y1))),
                        ToD3(camera.DirectionThrough(float(x0), float(y1)))};
  const D3 centre = ToD3(camera.DirectionThrough(0.5f * float(x0 + x1), 0.5f * float(y0 + y1)));
  D3 inward[4];  // unit normals of the pyramid's sides, pointing in
  for (int i = 0; i < 4; ++i) {
    D3 n = Cross(corner[i], corner[(i + 1) % 4]);
    const double length = std::sqrt(Dot(n, n));
    n = {n.x / length, n.y / length, n.z / length};
    if (Dot(n, centre) < 0.0) n = {-n.x, -n.y, -n.z};
    inward[i] = n;
  }
  for (uint32_t t = 0; t < triangles.size(); ++t) {
    const TriangleD& tri = triangles[t];
    const D3 a = Sub(tri.p0, origin);
    const D3 b = {a.x + tri.e1.x, a.y + tri.e1.y, a.z + tri.e1.z};
    const D3 c = {a.x + tri.e2.x, a.y + tri.e2.y, a.z + tri.e2.z};
    const double slack = 2.0 * tieBary * tri.extent + 1e-9 * (1.0 + std::sqrt(Dot(a, a)) + tri.extent);
    bool outside = false;
    for (int i = 0; i < 4 && !outside; ++i)
      outside = Dot(inward[i], a) < -slack && Dot(inward[i], b) < -slack && Dot(inward[i], c) < -slack;
    if (!outside) out.push_back(t);
  }
}

// Classifies the ray through every pixel centre, tile by tile; `use(x, y, pixel)`.
template <typename Use>
void ForEachPixel(const Scene& scene, const CameraView& view, double tieBary, bool asRoots, Use&& use) {
  const PinholeCamera camera(view);
  const D3 origin = ToD3(camera.Origin());
  const std::vector<TriangleD> triangles = TrianglesOf(scene);
  std::vector<uint32_t> candidates;
  std::vector<Candidate> hits;
  for (int ty = 0; ty < view.height; ty += kTile) {
    for (int tx = 0; tx < view.width; tx += kTile) {
      const int x1 = std::min(tx + kTile, view.width), y1 = std::min(ty + kTile, view.height);
      TileCandidates(camera, origin, triangles, tx, ty, x1, y1, tieBary, candidates);
      for (int y = ty; y < y1; ++y) {
        for (int x = tx; x < x1; ++x) {
          const D3 dir = ToD3(camera.DirectionThrough(float(x) + 0.5f, float(y) + 0.5f));
          use(x, y, ClassifyPixel(scene, triangles, candidates, origin, dir, tieBary, asRoots, hits));
        }
      }
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
