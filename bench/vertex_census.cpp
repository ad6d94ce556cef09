// Which vertex samples do not represent the surface around them?
//
// For every shading vertex of the chosen materials (both sides on a
// two-sided scene), shades the sample the SMA would ask for -- the vertex on
// the lowest-numbered triangle that uses it, with its vertex normal -- and,
// for each triangle using the vertex, a point a third of the way from the
// vertex to that triangle's centroid. A vertex is "dark" when its irradiance
// is below half the median of those nearby interior points (and they are not
// all black): interpolated from it, its triangles would be darker than their
// own insides. For each dark vertex the census looks at its geometry from the
// shader's ray origin: the fraction of cosine-distributed probe rays that
// meet a surface within the distance R to the centroid of its triangle
// (`near`), the fraction meeting a front face, and whether the way from that
// centroid to the sample crosses a surface (`blocked`, and the facing of the
// first crossing). It also counts the samples whose first estimate (16
// paths, as the SMA's first image asks) is exactly black but which are lit
// at --paths. Prints a summary, and one CSV line per dark vertex with --csv.
//
// Other modes (docs/refinement.md, third round):
//   --inspect V          the geometry on the way from vertex V to its
//                        triangle's centroid: crossings, probes, irradiance;
//   --noise R            R independent --paths estimates of each sample:
//                        the noise of one, and whether the shader's standard
//                        error says it;
//   --simulate-improvement  the SMA's improvement rounds on each sample, with
//                        and without stopping at a black estimate, against a
//                        --paths estimate;
//   --gouraud R          linear interpolation of the corners against the
//                        centroid on triangles reaching R or more;
//   --snapshot FILE      an SMA's cache on disk (--cache-dir): its samples
//                        against --paths estimates of themselves (bias and
//                        noise of the vertex values), and its leaves' linear
//                        interpolation against the surface itself (bias of
//                        the mesh), both per material; with --camera NAME the
//                        leaves weigh what that preset sees of them, and
//                        --csv writes one line per leaf (corner values, which
//                        corners the camera sees).
//
//   vertex_census --scene scenes/grey-white-room.json --material Sofa [--paths 256] [--stride 32] [--csv out.csv]

#include <algorithm>
#include <cmath>
#include <atomic>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <unordered_map>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include <CLI/CLI.hpp>

#include "penumbra/common/logging.h"
#include "penumbra/common/rng.h"
#include "penumbra/common/scene.h"
#include "penumbra/renderer/ray_scene.h"
#include "penumbra/renderer/shading.h"
#include "penumbra/sma/cache_snapshot.h"
#include "penumbra/sma/shade_codec.h"

namespace penumbra {
namespace {

namespace fs = std::filesystem;

struct Options {
  fs::path scene;
  std::vector<std::string> materials;  // substrings of material names; empty: all
  int paths = 32;
  int stride = 1;
  int probes = 32;
  int threads = 2;
  std::string csv;
  float minInteriorE = 0.05f;
  int firstPaths = 16;
  std::vector<int64_t> inspect;
  bool inspectBack = false;
  bool simulate = false;
  int noiseRepeats = 0;
  int blackPaths = 80;  // SampleCache::kBlackPaths
  float gouraudMinReach = 0.0f;
  std::string snapshot;
  std::string camera;  // --snapshot: weigh leaves by what this preset's camera sees of them
};

struct Row {
  uint32_t vertex = 0;
  bool back = false;
  std::string material;
  float vertexE = 0.0f, interiorE = 0.0f;
  float nearFraction = 0.0f, frontFraction = 0.0f, reach = 0.0f, escapeFraction = 0.0f, medianDistance = 0.0f;
  float cosNormalFace = 0.0f;
  int crossings = 0;
  int firstCrossingFront = -1;  // 1 front, 0 back, -1 none
  bool buriedRuleFired = false;
  Vec3 position;
};

// The geometry around one vertex sample (front side), on the way from it to
// its triangle's centroid: the surfaces that way crosses, and at points
// along it how many of 64 probes meet a surface within R/8, within R, or
// nothing, and the median hit distance.
void Inspect(const Scene& scene, const RayScene& rays, const Shader& shader, uint32_t v, uint32_t base, bool back) {
  const Vec3 normal = back ? -scene.vertices[v].normal : scene.vertices[v].normal;
  Vec3 faceNormal = scene.GeometricNormal(base);
  if (glm::dot(faceNormal, normal) < 0.0f) faceNormal = -faceNormal;
  const Vec3 extent = glm::max(glm::abs(scene.bounds.min), glm::abs(scene.bounds.max));
  const float offset = 1e-5f * std::max({extent.x, extent.y, extent.z});
  const Vec3 position = scene.vertices[v].position;
  const Vec3 centroid = scene.PointAt(base, 1.0f / 3.0f, 1.0f / 3.0f) + offset * faceNormal;
  const Vec3 origin = position + offset * faceNormal;
  const float R = glm::length(centroid - origin);
  const Vec3 along = (centroid - origin) / R;
  std::printf("vertex %u (%s side) at (%g, %g, %g), normal (%.3f, %.3f, %.3f), triangle %u (%s), face (%.3f, %.3f, %.3f), R %.4g\n",
              v, back ? "back" : "front", position.x, position.y, position.z, normal.x, normal.y, normal.z, base,
              scene.MaterialOf(base).name.c_str(), faceNormal.x, faceNormal.y, faceNormal.z, R);
  for (float t = 0.0f;;) {
    const auto hit = rays.Intersect(origin, along, t, R);
    if (!hit) break;
    std::printf("  crossing at %.4g of %.4g: triangle %u (%s), %s face\n", hit->t, R, hit->triangle,
                scene.MaterialOf(hit->triangle).name.c_str(), glm::dot(hit->normal, along) < 0 ? "front" : "back");
    t = hit->t + offset;
  }
  const Frame frame = Frame::FromNormal(glm::normalize(normal));
  for (float f : {0.0f, 1.0f / 256, 1.0f / 64, 1.0f / 16, 1.0f / 8, 1.0f / 4, 1.0f / 2, 1.0f}) {
    const Vec3 p = origin + f * R * along;
    Pcg32 rng(5, 7);
    int near8 = 0, nearR = 0, escape = 0;
    std::vector<float> d;
    std::vector<std::string> mats;
    for (int k = 0; k < 64; ++k) {
      const float r = std::sqrt(rng.NextFloat()), phi = 2.0f * kPi * rng.NextFloat();
      const Vec3 dir = frame.ToWorld(Vec3(r * std::cos(phi), r * std::sin(phi), std::sqrt(std::max(0.0f, 1 - r * r))));
      if (glm::dot(dir, faceNormal) <= 0.0f) { ++near8; ++nearR; d.push_back(0); continue; }
      const auto hit = rays.Intersect(p, dir, 0.0f, 1e30f);
      if (!hit) { ++escape; d.push_back(1e30f); continue; }
      near8 += hit->t < R / 8;
      nearR += hit->t < R;
      d.push_back(hit->t);
      if (k < 6) mats.push_back(scene.MaterialOf(hit->triangle).name + (glm::dot(hit->normal, dir) < 0 ? "+" : "-"));
    }
    std::nth_element(d.begin(), d.begin() + 32, d.end());
    // Irradiance there, with the sample's frame, on the base triangle (barycentrics approximate).
    ShadeInput in;
    in.position = p - offset * faceNormal;
    in.normal = normal;
    in.triangle = base;
    const auto& c = scene.triangles[base].v;
    const Vec2 b0 = c[1] == v ? Vec2(1, 0) : c[2] == v ? Vec2(0, 1) : Vec2(0, 0);
    const Vec2 b = b0 + (Vec2(1.0f / 3.0f) - b0) * f;
    in.b1 = b.x;
    in.b2 = b.y;
    in.position = scene.PointAt(base, b.x, b.y);
    ShadeCounters counters;
    const float e = Luminance(shader.Shade(in, 256, &counters).irradiance);
    std::string m;
    for (auto& x : mats) m += x + " ";
    std::printf("  at %.4f of the way: within R/8 %2d, within R %2d, escape %2d of 64, median distance %.3g, E %.4g%s  hits: %s\n",
                double(f), near8, nearR, escape, double(d[32]), double(e), counters.buriedSamples ? " (moved)" : "", m.c_str());
  }
}

// The SMA's improvement of one sample (sma/README.md, "Improvement"): a
// first estimate of `first` paths, then rounds of `round` paths, averaged in
// weighted by paths, while the relative standard error is above `target` and
// fewer than `cap` paths are in; each round on its own random stream. Returns
// the final irradiance luminance under the rule that stops at a black
// estimate (before this round's change) and under the one that improves it
// until `blackPaths` paths found nothing, and a reference estimate of
// `referencePaths` paths.
struct Improved {
  double stopAtBlack = 0.0, keepLooking = 0.0, reference = 0.0;
  uint32_t pathsStopAtBlack = 0, pathsKeepLooking = 0;
};

Improved SimulateImprovement(const Shader& shader, ShadeInput in, int first, int round, int cap, double target,
                             int referencePaths, int blackPaths) {
  Improved r;
  const uint64_t id = in.sampleId;
  ShadeOutput out = shader.Shade(in, first, nullptr);
  double mean = Luminance(out.irradiance), err = out.irradianceStdErr;
  uint32_t paths = out.paths;
  bool stoppedOld = false;
  for (uint64_t k = 1;; ++k) {
    const bool black = !(mean > 0.0);
    // Black: unknown until blackPaths paths found nothing (SampleCache::kBlackPaths).
    const bool uncertain = black ? paths < uint32_t(blackPaths) : err / mean > target;
    if (!stoppedOld && (paths >= uint32_t(cap) || black || !(err / mean > target))) {
      stoppedOld = true;
      r.stopAtBlack = mean;
      r.pathsStopAtBlack = paths;
    }
    if (paths >= uint32_t(cap) || !uncertain) break;
    in.sampleId = id + (k << 32);
    const ShadeOutput more = shader.Shade(in, round, nullptr);
    const double n1 = paths, n2 = more.paths, n = n1 + n2, w1 = n1 / n, w2 = n2 / n;
    mean = w1 * mean + w2 * Luminance(more.irradiance);
    err = std::sqrt(w1 * w1 * err * err + w2 * w2 * double(more.irradianceStdErr) * more.irradianceStdErr);
    paths += more.paths;
  }
  if (!stoppedOld) {
    r.stopAtBlack = mean;
    r.pathsStopAtBlack = paths;
  }
  r.keepLooking = mean;
  r.pathsKeepLooking = paths;
  in.sampleId = id + (uint64_t(1) << 50);
  r.reference = Luminance(shader.Shade(in, referencePaths, nullptr).irradiance);
  return r;
}

// Linear interpolation of the three vertex samples against the triangle's
// own irradiance at its centroid, over the chosen triangles whose centroid
// is at least `minReach` from their first corner (big ones), each side that
// is lit: what a base triangle shows before any refinement. The vertices are
// shaded as the SMA asks for them (on their lowest-numbered triangle).
int Gouraud(const Options& o, const Scene& scene, const Shader& shader,
            const std::vector<std::vector<uint32_t>>& trianglesOf, const std::function<bool(uint32_t)>& chosen) {
  std::vector<uint32_t> triangles;
  size_t counter = 0;
  for (uint32_t t = 0; t < scene.triangles.size(); ++t) {
    if (!chosen(t)) continue;
    const Vec3 c = scene.PointAt(t, 1.0f / 3.0f, 1.0f / 3.0f);
    if (glm::length(c - scene.Position(t, 0)) < o.gouraudMinReach) continue;
    if (counter++ % size_t(o.stride) == 0) triangles.push_back(t);
  }
  const auto cornerBary = [&](uint32_t t, uint32_t v) {
    const auto& c = scene.triangles[t].v;
    return c[1] == v ? Vec2(1, 0) : c[2] == v ? Vec2(0, 1) : Vec2(0, 0);
  };
  double interpolatedSum = 0.0, centroidSum = 0.0, absSum = 0.0;
  size_t sides = 0, darker = 0;
  std::vector<double> ratios;
  for (size_t i = 0; i < triangles.size(); ++i) {
    const uint32_t t = triangles[i];
    for (int side = 0; side < (scene.twoSided ? 2 : 1); ++side) {
      double corners = 0.0;
      Vec3 normalSum(0.0f);
      for (int k = 0; k < 3; ++k) {
        const uint32_t v = scene.triangles[t].v[size_t(k)];
        const uint32_t base = trianglesOf[v].front();
        ShadeInput in;
        in.sampleId = uint64_t(v) * 2 + uint64_t(side);
        in.position = scene.vertices[v].position;
        in.normal = side ? -scene.vertices[v].normal : scene.vertices[v].normal;
        normalSum += in.normal;
        in.triangle = base;
        const Vec2 b = cornerBary(base, v);
        in.b1 = b.x;
        in.b2 = b.y;
        corners += Luminance(shader.Shade(in, o.paths, nullptr).irradiance) / 3.0;
      }
      ShadeInput in;
      in.sampleId = (uint64_t(1) << 40) + uint64_t(t) * 2 + uint64_t(side);
      in.position = scene.PointAt(t, 1.0f / 3.0f, 1.0f / 3.0f);
      in.normal = glm::normalize(normalSum);
      in.triangle = t;
      in.b1 = in.b2 = 1.0f / 3.0f;
      const double centre = Luminance(shader.Shade(in, o.paths, nullptr).irradiance);
      if (!(centre > o.minInteriorE)) continue;  // the unlit side (outside, inside a solid)
      interpolatedSum += corners;
      centroidSum += centre;
      absSum += std::abs(corners - centre);
      darker += corners < centre;
      ratios.push_back(corners / centre);
      ++sides;
    }
  }
  std::printf("%zu lit sides of %zu triangles reaching %.2f or more: interpolated over centroid %.4f "
              "(mean abs. difference %.4f of the centroids' mean), interpolation darker on %zu\n",
              sides, triangles.size(), double(o.gouraudMinReach), interpolatedSum / centroidSum,
              absSum / centroidSum, darker);
  std::sort(ratios.begin(), ratios.end());
  if (!ratios.empty())
    std::printf("interpolated / centroid per side: 10th %.3f, 25th %.3f, median %.3f, 75th %.3f, 90th %.3f\n",
                ratios[ratios.size() / 10], ratios[ratios.size() / 4], ratios[ratios.size() / 2],
                ratios[ratios.size() * 3 / 4], ratios[ratios.size() * 9 / 10]);
  return 0;
}

// An SMA's cache snapshot against the surface. Vertex values: every
// stride-th cached sample against a --paths estimate of the same request
// (the cache's bias and noise). Mesh: every stride-th leaf whose corners are
// all shaded, its linear interpolation against the surface, by the
// edge-midpoint rule (exact for a quadratic: the triangle's mean is the mean
// of its three edge midpoints, and interpolation's there is the mean of the
// edges' ends) -- with the --paths estimates at the corners, so noise in the
// cache does not count, and with the cache's own corner values, which is
// what the client shows. Sums are weighted by leaf area, per material.
int Snapshot(const Options& o, const Scene& scene, const RayScene& rays, const Shader& shader,
             const std::function<bool(uint32_t)>& chosen) {
  const CameraPreset* camera = nullptr;
  if (!o.camera.empty() && !(camera = scene.FindCamera(o.camera))) {
    std::fprintf(stderr, "no camera %s in the scene\n", o.camera.c_str());
    return 1;
  }
  // The solid angle a leaf's point stands for, as the camera sees it: 0 when
  // hidden or outside a 16:9 view.
  std::optional<PinholeCamera> pinhole;
  if (camera) pinhole.emplace(CameraView{camera->pose, camera->fovYDeg, 1920, 1080});  // a 16:9 view
  const auto seenWeight = [&](Vec3 p, Vec3 normal) -> double {
    if (!pinhole) return 1.0;
    const std::optional<Vec2> pixel = pinhole->PixelOf(p);
    if (!pixel || pixel->x < 0.0f || pixel->x > float(pinhole->Width()) || pixel->y < 0.0f ||
        pixel->y > float(pinhole->Height()))
      return 0.0;
    const Vec3 d = p - pinhole->Origin();
    const float dist = glm::length(d);
    if (rays.Occluded(pinhole->Origin(), d / dist, 0.0f, dist * (1.0f - 1e-4f))) return 0.0;
    return std::abs(double(glm::dot(normal, d / dist))) / double(dist * dist);
  };
  std::ifstream file(o.snapshot, std::ios::binary);
  std::vector<char> bytes((std::istreambuf_iterator<char>(file)), std::istreambuf_iterator<char>());
  if (!file.good() && !file.eof()) {
    std::fprintf(stderr, "cannot read %s\n", o.snapshot.c_str());
    return 1;
  }
  Expected<sma::RestoredCache> restored = sma::DecodeCacheSnapshot(bytes, scene, sma::RadianceBounds::ForScene(scene));
  if (!restored) {
    std::fprintf(stderr, "%s: %s\n", o.snapshot.c_str(), restored.error().message.c_str());
    return 1;
  }
  const sma::Hierarchy& h = restored->hierarchy;
  std::unordered_map<sma::VertexId, const sma::ShadedSample*> cached;
  for (const sma::ShadedSample& s : restored->samples) cached.emplace(s.vertex, &s);
  const auto shadeAt = [&](uint64_t id, Vec3 position, Vec3 normal, uint32_t triangle, Vec2 bary) {
    ShadeInput in;
    in.sampleId = id;
    in.position = position;
    in.normal = normal;
    in.triangle = triangle;
    in.b1 = bary.x;
    in.b2 = bary.y;
    return double(Luminance(shader.Shade(in, o.paths, nullptr).irradiance));
  };
  struct Sums {
    double cacheE = 0, trueE = 0, absError = 0;  // vertices
    size_t vertices = 0, first = 0;
    double area = 0, interpTrue = 0, interpCache = 0, surface = 0, absInterp = 0;  // leaves, area-weighted
    size_t leaves = 0;
  };
  std::map<std::string, Sums> byMaterial;
  std::mutex mutex;
  std::ofstream csv;
  if (!o.csv.empty()) {
    csv.open(o.csv);
    csv << "material,depth,weight,true0,true1,true2,cache0,cache1,cache2,interp,surface,x0,y0,z0,x1,y1,z1,x2,y2,z2,v0,v1,v2,mid0,mid1,mid2,seen0,seen1,seen2,cornerSeen0,cornerSeen1,cornerSeen2\n";
  }
  // Vertex values.
  std::vector<const sma::ShadedSample*> samples;
  size_t counter = 0;
  for (const sma::ShadedSample& s : restored->samples)
    if (chosen(h.GetVertex(s.vertex).baseTriangle) && counter++ % size_t(o.stride) == 0) samples.push_back(&s);
  // Leaves with every corner shaded.
  std::vector<sma::NodeId> leaves;
  counter = 0;
  for (sma::NodeId id = 0; id < h.NodeCount(); ++id) {
    if (!h.Alive(id)) continue;
    const sma::Node& n = h.GetNode(id);
    if (!n.IsLeaf() || !chosen(n.baseTriangle)) continue;
    if (!std::all_of(n.v.begin(), n.v.end(), [&](sma::VertexId v) { return cached.contains(v); })) continue;
    if (counter++ % size_t(o.stride) == 0) leaves.push_back(id);
  }
  std::atomic<size_t> next{0};
  std::vector<std::thread> pool;
  for (int th = 0; th < o.threads; ++th)
    pool.emplace_back([&] {
      EnableFlushToZero();
      for (size_t i; (i = next.fetch_add(1)) < samples.size() + leaves.size();) {
        if (i < samples.size()) {
          const sma::ShadedSample& s = *samples[i];
          const sma::SampleRequest r = sma::MakeSampleRequest(h, s.vertex);
          const double truth = shadeAt((uint64_t(1) << 48) + s.vertex, r.position, r.normal, r.triangle, r.bary);
          const double value = Luminance(s.irradiance);
          std::lock_guard lock(mutex);
          Sums& m = byMaterial[scene.MaterialOf(r.triangle).name];
          m.cacheE += value;
          m.trueE += truth;
          m.absError += std::abs(value - truth);
          ++m.vertices;
          m.first += s.round == 0;
          continue;
        }
        const sma::Node& n = h.GetNode(leaves[i - samples.size()]);
        double cornerTrue[3], cornerCache[3];
        bool cornerSeen[3];
        for (int k = 0; k < 3; ++k) {
          const sma::SampleRequest r = sma::MakeSampleRequest(h, n.v[size_t(k)]);
          cornerTrue[k] = shadeAt((uint64_t(2) << 48) + n.v[size_t(k)], r.position, r.normal, r.triangle, r.bary);
          cornerCache[k] = Luminance(cached.at(n.v[size_t(k)])->irradiance);
          cornerSeen[k] = seenWeight(r.position, r.normal) > 0.0;
        }
        double midpoints = 0, interpTrue = 0, interpCache = 0, seen = 0, mid[3], midSeen[3];
        for (int k = 0; k < 3; ++k) {  // edge k joins corners k+1 and k+2
          const int a = (k + 1) % 3, b = (k + 2) % 3;
          const Vec2 bary = 0.5f * (n.bary[size_t(a)] + n.bary[size_t(b)]);
          const Vec3 sum = h.GetVertex(n.v[size_t(a)]).normal + h.GetVertex(n.v[size_t(b)]).normal;
          const Vec3 normal = glm::length(sum) > 1e-6f ? glm::normalize(sum) : h.GetVertex(n.v[size_t(a)]).normal;
          const Vec3 at = scene.PointAt(n.baseTriangle, bary.x, bary.y);
          mid[k] = shadeAt((uint64_t(3) << 48) + uint64_t(leaves[i - samples.size()]) * 3 + uint64_t(k), at, normal,
                           n.baseTriangle, bary);
          midSeen[k] = seenWeight(at, normal);
          midpoints += mid[k] / 3;
          seen += midSeen[k] / 3;
          interpTrue += 0.5 * (cornerTrue[a] + cornerTrue[b]) / 3;
          interpCache += 0.5 * (cornerCache[a] + cornerCache[b]) / 3;
        }
        const Vec3 p0 = h.GetVertex(n.v[0]).position, p1 = h.GetVertex(n.v[1]).position,
                   p2 = h.GetVertex(n.v[2]).position;
        const double area = 0.5 * double(glm::length(glm::cross(p1 - p0, p2 - p0))) * seen;
        if (!(area > 0.0)) continue;
        std::lock_guard lock(mutex);
        if (csv.is_open())
          csv << scene.MaterialOf(n.baseTriangle).name << ',' << int(n.depth) << ',' << area << ',' << cornerTrue[0]
              << ',' << cornerTrue[1] << ',' << cornerTrue[2] << ',' << cornerCache[0] << ',' << cornerCache[1] << ','
              << cornerCache[2] << ',' << interpTrue << ',' << midpoints << ',' << p0.x << ',' << p0.y << ','
              << p0.z << ',' << p1.x << ',' << p1.y << ',' << p1.z << ',' << p2.x << ',' << p2.y << ',' << p2.z
              << ',' << n.v[0] << ',' << n.v[1] << ',' << n.v[2] << ',' << mid[0] << ',' << mid[1] << ',' << mid[2]
              << ',' << midSeen[0] << ',' << midSeen[1] << ',' << midSeen[2] << ',' << cornerSeen[0] << ','
              << cornerSeen[1] << ',' << cornerSeen[2] << '\n';
        Sums& m = byMaterial[scene.MaterialOf(n.baseTriangle).name];
        m.area += area;
        m.interpTrue += area * interpTrue;
        m.interpCache += area * interpCache;
        m.surface += area * midpoints;
        m.absInterp += area * std::abs(interpTrue - midpoints);
        ++m.leaves;
      }
    });
  for (auto& t : pool) t.join();
  std::vector<std::pair<std::string, Sums>> rows(byMaterial.begin(), byMaterial.end());
  Sums all;
  for (const auto& [name, m] : rows) {
    all.cacheE += m.cacheE, all.trueE += m.trueE, all.absError += m.absError, all.vertices += m.vertices;
    all.first += m.first, all.area += m.area, all.interpTrue += m.interpTrue, all.interpCache += m.interpCache;
    all.surface += m.surface, all.absInterp += m.absInterp, all.leaves += m.leaves;
  }
  rows.emplace_back("(all)", all);
  std::sort(rows.begin(), rows.end(), [](const auto& a, const auto& b) { return a.second.area > b.second.area; });
  std::printf("%zu of %zu samples, %zu leaves; truth: %d paths a point; leaves weighted by %s\n", samples.size(),
              restored->samples.size(), leaves.size(), o.paths,
              camera ? "the solid angle the camera sees of them" : "area");
  std::printf("%-28s %8s %6s %9s %9s | %7s %8s %13s %12s %10s\n", "material", "samples", "first", "cache/true",
              "|err|/true", "leaves", "area", "interp/surface", "|interp-surf|", "shown/surf");
  for (const auto& [name, m] : rows) {
    if (m.vertices == 0 && m.leaves == 0) continue;
    std::printf("%-28.28s %8zu %6zu %9.4f %9.4f | %7zu %8.3f %13.4f %12.4f %10.4f\n", name.c_str(), m.vertices, m.first,
                m.cacheE / m.trueE, m.absError / m.trueE, m.leaves, m.area, m.interpTrue / m.surface,
                m.absInterp / m.surface, m.interpCache / m.surface);
  }
  return 0;
}

int Run(const Options& o) {
  Expected<Scene> loaded = LoadScene(o.scene);
  if (!loaded) {
    std::fprintf(stderr, "%s\n", loaded.error().message.c_str());
    return 1;
  }
  const Scene& scene = *loaded;
  Expected<std::unique_ptr<RayScene>> built = RayScene::Build(scene);
  if (!built) {
    std::fprintf(stderr, "%s\n", built.error().message.c_str());
    return 1;
  }
  const RayScene& rays = **built;
  const Shader shader(scene, rays, ShadingSettings{});

  // Triangles per vertex, and the lowest-numbered one (the SMA's choice).
  std::vector<std::vector<uint32_t>> trianglesOf(scene.vertices.size());
  for (uint32_t t = 0; t < scene.triangles.size(); ++t)
    for (uint32_t v : scene.triangles[t].v)
      if (trianglesOf[v].empty() || trianglesOf[v].back() != t) trianglesOf[v].push_back(t);
  if (!o.inspect.empty()) {
    for (int64_t v : o.inspect)
      if (v >= 0 && size_t(v) < scene.vertices.size() && !trianglesOf[size_t(v)].empty())
        Inspect(scene, rays, shader, uint32_t(v), trianglesOf[size_t(v)].front(), o.inspectBack);
    return 0;
  }
  const std::function<bool(uint32_t)> chosen = [&](uint32_t t) {
    if (o.materials.empty()) return true;
    const std::string& name = scene.MaterialOf(t).name;
    return std::any_of(o.materials.begin(), o.materials.end(),
                       [&](const std::string& m) { return name.find(m) != std::string::npos; });
  };
  if (o.gouraudMinReach > 0.0f) return Gouraud(o, scene, shader, trianglesOf, chosen);
  if (!o.snapshot.empty()) return Snapshot(o, scene, rays, shader, chosen);
  std::vector<std::pair<uint32_t, bool>> work;  // vertex, back side
  size_t counter = 0;
  for (uint32_t v = 0; v < scene.vertices.size(); ++v) {
    if (trianglesOf[v].empty() || !chosen(trianglesOf[v].front())) continue;
    if (counter++ % size_t(o.stride) != 0) continue;
    work.emplace_back(v, false);
    if (scene.twoSided) work.emplace_back(v, true);
  }
  const Vec3 extent = glm::max(glm::abs(scene.bounds.min), glm::abs(scene.bounds.max));
  const float offset = 1e-5f * std::max({extent.x, extent.y, extent.z});

  const auto cornerBary = [&](uint32_t t, uint32_t v) {
    const auto& c = scene.triangles[t].v;
    return c[1] == v ? Vec2(1, 0) : c[2] == v ? Vec2(0, 1) : Vec2(0, 0);
  };
  std::vector<Row> dark;
  std::mutex darkMutex;
  std::atomic<size_t> next{0}, shaded{0}, buriedFired{0}, zeroFirst{0}, zeroFirstButLit{0};
  std::vector<float> zeroFirstLitE;
  std::vector<Improved> improved;
  struct Noise {
    double mean = 0.0, spread = 0.0, claimed = 0.0;  // luminance of E; spread and claimed: one estimate's
  };
  std::vector<Noise> noise;
  std::vector<int> nearHistAll(11, 0), nearHistDark(11, 0);
  std::vector<std::thread> pool;
  for (int th = 0; th < o.threads; ++th)
    pool.emplace_back([&] {
      EnableFlushToZero();
      for (size_t i; (i = next.fetch_add(1)) < work.size();) {
        const auto [v, back] = work[i];
        const uint32_t base = trianglesOf[v].front();
        const Vec3 normal = back ? -scene.vertices[v].normal : scene.vertices[v].normal;
        ShadeInput in;
        in.sampleId = i;
        in.position = scene.vertices[v].position;
        in.normal = normal;
        in.triangle = base;
        const Vec2 b = cornerBary(base, v);
        in.b1 = b.x;
        in.b2 = b.y;
        if (o.noiseRepeats > 0) {
          // Independent --paths estimates of the one sample (their ids apart
          // as the SMA's improvement rounds are): their spread is the noise
          // of one estimate, and the shader's own standard error is compared
          // with it.
          double sum = 0.0, squares = 0.0, claimed = 0.0;
          for (int r = 0; r < o.noiseRepeats; ++r) {
            in.sampleId = uint64_t(i) + (uint64_t(r + 1) << 32);
            const ShadeOutput out = shader.Shade(in, o.paths, nullptr);
            const double l = Luminance(out.irradiance);
            sum += l;
            squares += l * l;
            claimed += double(out.irradianceStdErr) * out.irradianceStdErr;
          }
          const double n = o.noiseRepeats, mean = sum / n;
          if (mean > 0.0) {
            std::lock_guard lock(darkMutex);
            noise.push_back({mean, std::sqrt(std::max(0.0, (squares / n - mean * mean) * n / (n - 1.0))),
                             std::sqrt(claimed / n)});
          }
          continue;
        }
        if (o.simulate) {
          const Improved r = SimulateImprovement(shader, in, o.firstPaths, 64, 1024, 0.02, o.paths, o.blackPaths);
          std::lock_guard lock(darkMutex);
          improved.push_back(r);
          continue;
        }
        ShadeCounters counters;
        const float vertexE = Luminance(shader.Shade(in, o.paths, &counters).irradiance);
        // A first estimate as the SMA's first image asks for it: how often does
        // it read exactly 0 (every path found nothing), with a standard error
        // of 0, where many paths find light?
        {
          const ShadeOutput first = shader.Shade(in, o.firstPaths, nullptr);
          if (Luminance(first.irradiance) == 0.0f) {
            ++zeroFirst;
            if (vertexE > 0.0f) {
              ++zeroFirstButLit;
              std::lock_guard lock(darkMutex);
              zeroFirstLitE.push_back(vertexE);
            }
          }
        }
        std::vector<float> interior;
        for (size_t k = 0; k < trianglesOf[v].size() && k < 8; ++k) {
          const uint32_t t = trianglesOf[v][k];
          const Vec2 c = cornerBary(t, v);
          const Vec2 inside = c + (Vec2(1.0f / 3.0f) - c) * (1.0f / 3.0f);
          Vec3 face = scene.GeometricNormal(t);
          if (glm::dot(face, normal) < 0.0f) face = -face;
          ShadeInput p;
          p.sampleId = i * 16 + k + (uint64_t(1) << 40);
          p.triangle = t;
          p.b1 = inside.x;
          p.b2 = inside.y;
          p.position = scene.PointAt(t, inside.x, inside.y);
          p.normal = face;
          interior.push_back(Luminance(shader.Shade(p, o.paths, nullptr).irradiance));
        }
        std::nth_element(interior.begin(), interior.begin() + interior.size() / 2, interior.end());
        const float interiorE = interior[interior.size() / 2];
        ++shaded;
        if (counters.buriedSamples) ++buriedFired;

        // Geometry seen from the shader's origin, and from the brightest interior point.
        Vec3 faceNormal = scene.GeometricNormal(base);
        if (glm::dot(faceNormal, normal) < 0.0f) faceNormal = -faceNormal;
        const Vec3 centroid = scene.PointAt(base, 1.0f / 3.0f, 1.0f / 3.0f);
        Vec3 toCentroid = centroid - in.position;
        const float reach = glm::length(toCentroid);
        Vec3 origin = in.position + offset * faceNormal;
        if (reach > 0.0f) origin += toCentroid * (std::min(offset, 0.5f * reach) / reach);
        const Frame frame = Frame::FromNormal(glm::normalize(normal));
        Pcg32 rng(99, i);
        int nearHits = 0, frontHits = 0, escapes = 0;
        std::vector<float> distances;
        for (int k = 0; k < o.probes; ++k) {
          const float r = std::sqrt(rng.NextFloat()), phi = 2.0f * kPi * rng.NextFloat();
          const Vec3 d = frame.ToWorld(Vec3(r * std::cos(phi), r * std::sin(phi), std::sqrt(std::max(0.0f, 1 - r * r))));
          if (glm::dot(d, faceNormal) <= 0.0f) { ++nearHits; distances.push_back(0.0f); continue; }
          const auto hit = rays.Intersect(origin, d, 0.0f, 1e30f);
          if (hit && hit->t < reach) ++nearHits;
          if (hit && glm::dot(hit->normal, d) < 0.0f) ++frontHits;
          if (!hit) ++escapes;
          distances.push_back(hit ? hit->t : 1e30f);
        }
        std::nth_element(distances.begin(), distances.begin() + distances.size() / 2, distances.end());
        const float medianDistance = distances[distances.size() / 2];
        const float nearFraction = float(nearHits) / float(o.probes);
        {
          std::lock_guard lock(darkMutex);
          ++nearHistAll[size_t(nearFraction * 10.0f + 0.5f)];
        }
        if (!(interiorE > o.minInteriorE && vertexE < 0.5f * interiorE)) continue;
        Row row;
        row.vertex = v;
        row.back = back;
        row.material = scene.MaterialOf(base).name;
        row.vertexE = vertexE;
        row.interiorE = interiorE;
        row.nearFraction = nearFraction;
        row.frontFraction = float(frontHits) / float(o.probes);
        row.reach = reach;
        row.escapeFraction = float(escapes) / float(o.probes);
        row.medianDistance = medianDistance;
        row.cosNormalFace = glm::dot(glm::normalize(normal), faceNormal);
        row.buriedRuleFired = counters.buriedSamples > 0;
        row.position = in.position;
        // Crossings on the way from the centroid (off the surface) to the sample.
        const Vec3 from = centroid + offset * faceNormal;
        const Vec3 way = origin - from;
        const float length = glm::length(way);
        if (length > 0.0f) {
          const Vec3 along = way / length;
          float t0 = 0.0f;
          for (int k = 0; k < 16; ++k) {
            const auto hit = rays.Intersect(from, along, t0, length);
            if (!hit) break;
            if (row.crossings == 0) row.firstCrossingFront = glm::dot(hit->normal, along) < 0.0f ? 1 : 0;
            ++row.crossings;
            t0 = hit->t + offset;
          }
        }
        std::lock_guard lock(darkMutex);
        ++nearHistDark[size_t(nearFraction * 10.0f + 0.5f)];
        dark.push_back(row);
      }
    });
  for (std::thread& t : pool) t.join();

  if (o.noiseRepeats > 0) {
    // Relative to the sum of the means, so that dim samples weigh as little
    // as they show; and the median of the per-sample relative spreads.
    double meanSum = 0.0, spreadSum = 0.0, claimedSum = 0.0;
    std::vector<double> relative;
    for (const Noise& r : noise) {
      meanSum += r.mean;
      spreadSum += r.spread;
      claimedSum += r.claimed;
      relative.push_back(r.spread / r.mean);
    }
    std::sort(relative.begin(), relative.end());
    std::printf("noise of one %d-path estimate, %d estimates of each of %zu lit samples:\n", o.paths, o.noiseRepeats,
                noise.size());
    std::printf("  spread / mean (sums) %.4f, median per sample %.4f; shader's own standard error / spread %.3f\n",
                spreadSum / meanSum, relative.empty() ? 0.0 : relative[relative.size() / 2], claimedSum / spreadSum);
    return 0;
  }
  if (o.simulate) {
    // Sums over the samples: the bias of each rule against the reference,
    // and the paths it spent.
    double oldSum = 0.0, newSum = 0.0, refSum = 0.0, oldAbs = 0.0, newAbs = 0.0;
    uint64_t oldPaths = 0, newPaths = 0;
    size_t blackOld = 0, blackNew = 0, blackRef = 0;
    for (const Improved& r : improved) {
      oldSum += r.stopAtBlack;
      newSum += r.keepLooking;
      refSum += r.reference;
      oldAbs += std::abs(r.stopAtBlack - r.reference);
      newAbs += std::abs(r.keepLooking - r.reference);
      oldPaths += r.pathsStopAtBlack;
      newPaths += r.pathsKeepLooking;
      blackOld += r.stopAtBlack == 0.0;
      blackNew += r.keepLooking == 0.0;
      blackRef += r.reference == 0.0;
    }
    std::printf("improvement simulated on %zu samples (first %d paths, rounds of 64 to 2 %% or 1024 paths), "
                "against %d-path estimates:\n",
                improved.size(), o.firstPaths, o.paths);
    std::printf("  stop at black:  mean ratio %.4f, rel. MAE %.4f, black %zu, paths %.1f per sample\n",
                oldSum / refSum, oldAbs / refSum, blackOld, double(oldPaths) / double(improved.size()));
    std::printf("  keep looking:   mean ratio %.4f, rel. MAE %.4f, black %zu, paths %.1f per sample\n",
                newSum / refSum, newAbs / refSum, blackNew, double(newPaths) / double(improved.size()));
    std::printf("  reference black: %zu\n", blackRef);
    return 0;
  }
  size_t blocked = 0, blockedFront = 0, fired = 0, enclosed = 0;
  for (const Row& r : dark) {
    blocked += r.crossings > 0;
    blockedFront += r.firstCrossingFront == 1;
    fired += r.buriedRuleFired;
    enclosed += r.nearFraction >= 0.875f;
  }
  std::printf("samples %zu (vertices x sides), dark %zu (%.1f %%), buried rule fired on %zu of all, %zu of the dark\n",
              shaded.load(), dark.size(), 100.0 * double(dark.size()) / double(std::max<size_t>(1, shaded)),
              buriedFired.load(), fired);
  std::sort(zeroFirstLitE.begin(), zeroFirstLitE.end());
  const auto quantile = [&](double q) {
    return zeroFirstLitE.empty() ? 0.0 : double(zeroFirstLitE[size_t(q * double(zeroFirstLitE.size() - 1))]);
  };
  std::printf("%d-path first estimate exactly 0 (standard error 0): %zu samples, of which %zu read > 0 at %d paths "
              "(their irradiance: median %.3g, 90th percentile %.3g)\n",
              o.firstPaths, zeroFirst.load(), zeroFirstButLit.load(), o.paths, quantile(0.5), quantile(0.9));
  std::printf("dark: way from the centroid blocked %zu (first crossing a front face %zu), near >= 7/8: %zu\n", blocked,
              blockedFront, enclosed);
  std::printf("near fraction (probes meeting a surface within R)  all / dark:\n");
  for (size_t k = 0; k < nearHistAll.size(); ++k)
    std::printf("  %.1f  %7d  %7d\n", double(k) / 10.0, nearHistAll[k], nearHistDark[k]);
  if (!o.csv.empty()) {
    std::ofstream out(o.csv);
    out << "vertex,back,material,vertexE,interiorE,near,front,escape,mediandist,cosNF,R,crossings,firstFront,buriedRule,x,y,z\n";
    for (const Row& r : dark)
      out << r.vertex << ',' << r.back << ',' << r.material << ',' << r.vertexE << ',' << r.interiorE << ','
          << r.nearFraction << ',' << r.frontFraction << ',' << r.escapeFraction << ',' << r.medianDistance << ','
          << r.cosNormalFace << ',' << r.reach << ',' << r.crossings << ','
          << r.firstCrossingFront << ',' << r.buriedRuleFired << ',' << r.position.x << ',' << r.position.y << ','
          << r.position.z << '\n';
  }
  return 0;
}

}  // namespace
}  // namespace penumbra

int main(int argc, char** argv) {
  penumbra::Options o;
  CLI::App app{"Counts vertex samples darker than the insides of their triangles, and describes their geometry"};
  app.add_option("--scene", o.scene, "scene file")->required();
  app.add_option("--material", o.materials, "only vertices whose triangle's material name contains this (repeatable)");
  app.add_option("--paths", o.paths, "paths per sample")->check(CLI::Range(1, 4096));
  app.add_option("--stride", o.stride, "every Nth vertex")->check(CLI::Range(1, 1 << 20));
  app.add_option("--probes", o.probes, "geometry probe rays per dark vertex")->check(CLI::Range(1, 4096));
  app.add_option("--threads", o.threads, "threads")->check(CLI::Range(1, 256));
  app.add_option("--min-interior", o.minInteriorE, "only interiors brighter than this irradiance (luminance) count");
  app.add_option("--first-paths", o.firstPaths, "paths of the first estimate (the SMA's first image)")->check(CLI::Range(1, 4096));
  app.add_option("--inspect", o.inspect, "describe these vertices' geometry instead (repeatable)");
  app.add_flag("--inspect-back", o.inspectBack, "... on their back side");
  app.add_flag("--simulate-improvement", o.simulate,
               "simulate the SMA's improvement of each sample instead, against a --paths estimate");
  app.add_option("--noise", o.noiseRepeats,
                 "shade each sample this many times with --paths paths instead: the spread of one estimate, and the "
                 "shader's standard error against it")
      ->check(CLI::Range(2, 1024));
  app.add_option("--gouraud", o.gouraudMinReach,
                 "compare linear interpolation of the corners with the centroid instead, on triangles whose centroid "
                 "is this far from a corner");
  app.add_option("--black-paths", o.blackPaths, "... taking a sample as black once this many paths found nothing")
      ->check(CLI::Range(1, 1 << 20));
  app.add_option("--snapshot", o.snapshot,
                 "measure this SMA cache snapshot's vertex values and leaves against the surface instead");
  app.add_option("--camera", o.camera, "--snapshot: weigh leaves by the solid angle this camera preset sees of them");
  app.add_option("--csv", o.csv, "write one line per dark vertex here");
  CLI11_PARSE(app, argc, argv);
  penumbra::SetupLogging("warn");
  return penumbra::Run(o);
}
