// motion_volume_bench: the speed and the selectivity of the SMA's move
// invalidation (sma/motion_volume.h) on a real scene.
//
// Static points are drawn uniformly by area over the scene's static
// triangles (a side each, at random in a two-sided scene), standing in for a
// cache's vertices, and shaded by the renderer's path tracer with a box-shaped
// object baked in at its old place. The box then moves; the bench reports
//  * the time per vertex of MoveInvalidator (one thread, and the bulk helper
//    on all threads), over the shaded points repeated up to --timed vertices;
//  * the fraction of points invalidated, and why (facing the box, in a light
//    shaft, in the sun's cone);
//  * with --verify, the points re-shaded with the box at its new place: how
//    many changed beyond 4 standard errors, and how many of those were kept
//    (must be 0: the invalidation is conservative);
//  * with --oracle-spp N, what an ideal invalidation would do at the same
//    tolerance: both places shaded again at N paths with common random
//    numbers (each point's paths use the same random sequence at both
//    places, so they differ only where they meet the box, and the change is
//    measured with far less noise than either estimate has), twice with
//    independent sequences. A point needs re-shading when its change
//    exceeds its tolerance tau; the count is the fewest samples any
//    invalidation at this tolerance could re-shade, and all / that count the
//    best ratio it could reach.

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "penumbra/common/logging.h"
#include "penumbra/common/scene.h"
#include "penumbra/renderer/ray_scene.h"
#include "penumbra/renderer/shading.h"
#include "penumbra/sma/motion_volume.h"

namespace penumbra {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

struct Options {
  fs::path scene = fs::path(PENUMBRA_SOURCE_DIR) / "scenes" / "breakfast-room.json";
  // The breakfast room's units are about a third of a metre (its table top
  // is 2.3 above the floor): a 1.5-unit cube (~0.5 m) standing on the floor
  // in the open part of the room, moved 0.3 units (~10 cm).
  std::vector<float> boxCenter{0.0f, -0.65f, 3.0f};
  float boxSize = 1.5f;
  std::vector<float> move{0.3f, 0.0f, 0.0f};
  int points = 20000;
  int spp = 64;
  int timed = 1000000;
  bool verify = false;
  float noiseZ = 1.0f;
  float relativeFloor = 0.01f;
  float margin = 2.0f;
  int oracleSpp = 0;
  int pairedPaths = 0;
  float pairedZ = 3.0f;
  int regionPaths = 0;
  float regionZ = 3.0f;
};

struct CachePoint {
  Vec3 position;
  Vec3 normal;
  uint32_t triangle;
  float b1, b2;
};

// The scene with an axis-aligned block (outward faces, albedo 0.7) added as
// its one movable object, placed at `centre`.
Expected<Scene> WithMovableBlock(const Scene& base, float blockSide, const Vec3& centre) {
  Scene s = base;
  Bounds3 block;  // object space
  block.Extend(Vec3(-0.5f * blockSide));
  block.Extend(Vec3(0.5f * blockSide));
  const uint32_t material = uint32_t(s.materials.size());
  Material m;
  m.name = "bench block";
  m.albedo = Rgb(0.7f);
  s.materials.push_back(m);
  const Vec3 lo = block.min, size = block.Diagonal();
  for (int axis = 0; axis < 3; ++axis) {
    for (int side = 0; side < 2; ++side) {
      Vec3 front(0.0f);
      front[axis] = side == 0 ? -1.0f : 1.0f;
      Vec3 corner = lo;
      corner[axis] = side == 0 ? lo[axis] : block.max[axis];
      Vec3 e1(0.0f), e2(0.0f);
      e1[(axis + 1) % 3] = size[(axis + 1) % 3];
      e2[(axis + 2) % 3] = size[(axis + 2) % 3];
      if (glm::dot(glm::cross(e1, e2), front) < 0.0f) std::swap(e1, e2);
      const uint32_t v0 = uint32_t(s.vertices.size());
      for (const Vec3& p : {corner, corner + e1, corner + e1 + e2, corner + e2}) s.vertices.push_back({p, front});
      Triangle t0, t1;
      t0.v = {v0, v0 + 1, v0 + 2};
      t1.v = {v0, v0 + 2, v0 + 3};
      t0.material = t1.material = material;
      s.triangles.push_back(t0);
      s.triangles.push_back(t1);
    }
  }
  if (!base.objects.empty()) return Fail("the bench adds its own block; scenes with movable objects are not supported");
  MovableObject object;
  object.name = "bench block";
  object.firstTriangle = uint32_t(base.triangles.size());
  object.triangleCount = uint32_t(s.triangles.size() - base.triangles.size());
  object.firstVertex = uint32_t(base.vertices.size());
  object.vertexCount = uint32_t(s.vertices.size() - base.vertices.size());
  object.objectToWorld = RigidTransform{glm::mat3(1.0f), centre};
  s.objects.push_back(object);
  if (Status ok = s.Finalize(); !ok) return ok.error();
  return s;
}

std::vector<CachePoint> DrawPoints(const Scene& scene, int count) {
  std::vector<double> cdf;
  double total = 0.0;
  for (uint32_t t = 0; t < scene.staticTriangleCount; ++t) {
    total += scene.MaterialOf(t).IsEmissive() ? 0.0 : scene.Area(t);
    cdf.push_back(total);
  }
  std::mt19937_64 rng(14);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<CachePoint> points;
  for (int i = 0; i < count; ++i) {
    const uint32_t t = uint32_t(std::lower_bound(cdf.begin(), cdf.end(), u(rng) * total) - cdf.begin());
    float b1 = float(u(rng)), b2 = float(u(rng));
    if (b1 + b2 > 1.0f) {
      b1 = 1.0f - b1;
      b2 = 1.0f - b2;
    }
    Vec3 n = scene.GeometricNormal(t);
    if (scene.twoSided && u(rng) < 0.5) n = -n;
    points.push_back({scene.PointAt(t, b1, b2), n, t, b1, b2});
  }
  return points;
}

struct Shaded {
  std::vector<float> irradiance, stdErr;
  float brightestRadiance = 0.0f;  // luminance, non-emissive points
};

ShadeInput InputOf(const CachePoint& p, uint64_t sampleId) {
  ShadeInput in;
  in.sampleId = sampleId;
  in.position = p.position;
  in.normal = p.normal;
  in.triangle = p.triangle;
  in.b1 = p.b1;
  in.b2 = p.b2;
  return in;
}

Shaded Shade(const Shader& shader, const PosedRayScene& at, const std::vector<CachePoint>& points, int spp,
             uint64_t seedBase) {
  Shaded out;
  out.irradiance.resize(points.size());
  out.stdErr.resize(points.size());
  std::vector<float> radiance(points.size());
  tbb::parallel_for(tbb::blocked_range<size_t>(0, points.size(), 64), [&](const tbb::blocked_range<size_t>& r) {
    for (size_t i = r.begin(); i != r.end(); ++i) {
      const ShadeOutput o = shader.Shade(at, InputOf(points[i], seedBase + i), spp, nullptr);
      out.irradiance[i] = Luminance(o.irradiance);
      out.stdErr[i] = o.irradianceStdErr;
      radiance[i] = Luminance(o.radiance);
    }
  });
  for (float r : radiance) out.brightestRadiance = std::max(out.brightestRadiance, r);
  return out;
}

double Seconds(Clock::time_point since) { return std::chrono::duration<double>(Clock::now() - since).count(); }

int Run(const Options& o) {
  SetupLogging("warn");
  auto loaded = LoadScene(o.scene);
  if (!loaded) {
    std::fprintf(stderr, "motion_volume_bench: %s\n", loaded.error().message.c_str());
    return 1;
  }
  const Vec3 centre(o.boxCenter[0], o.boxCenter[1], o.boxCenter[2]);
  const Vec3 move(o.move[0], o.move[1], o.move[2]);
  Bounds3 before, after;
  before.Extend(centre - Vec3(0.5f * o.boxSize));
  before.Extend(centre + Vec3(0.5f * o.boxSize));
  after.Extend(before.min + move);
  after.Extend(before.max + move);
  const Bounds3& b = loaded->bounds;
  std::printf("scene %s: %zu triangles, bounds (%.2f %.2f %.2f)-(%.2f %.2f %.2f), %zu area-light triangles%s%s\n",
              loaded->name.c_str(), loaded->triangles.size(), b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z,
              loaded->emissiveTriangles.size(), loaded->sun ? ", sun" : "", loaded->sky ? ", sky" : "");
  std::printf("box %.2f units at (%.2f %.2f %.2f), moved by (%.2f %.2f %.2f)\n", o.boxSize, centre.x, centre.y, centre.z,
              move.x, move.y, move.z);

  // One scene with the box as its movable object, shaded at two poses.
  auto old = WithMovableBlock(*loaded, o.boxSize, centre);
  if (!old) {
    std::fprintf(stderr, "motion_volume_bench: %s\n", old.error().message.c_str());
    return 1;
  }
  auto rays = RayScene::Build(*old);
  if (!rays) {
    std::fprintf(stderr, "motion_volume_bench: %s\n", rays.error().message.c_str());
    return 1;
  }
  const Shader shader(*old, **rays, ShadingSettings{});
  const PosedRayScene& atOld = *(*rays)->Initial();
  ScenePose movedPose = ScenePose::Initial(*old);
  movedPose.epoch = 1;
  movedPose.objectToWorld[0] = RigidTransform{glm::mat3(1.0f), centre + move};
  auto posedNew = (*rays)->AtPose(movedPose);
  if (!posedNew) {
    std::fprintf(stderr, "motion_volume_bench: %s\n", posedNew.error().message.c_str());
    return 1;
  }
  const PosedRayScene& atNew = **posedNew;
  const std::vector<CachePoint> points = DrawPoints(*old, o.points);
  Clock::time_point t0 = Clock::now();
  const Shaded cached = Shade(shader, atOld, points, o.spp, 0);
  std::printf("shaded %zu points at %d paths in %.1f s; brightest non-emissive radiance %.3f\n", points.size(), o.spp,
              Seconds(t0), cached.brightestRadiance);

  sma::InvalidationParams params;
  params.noiseZ = o.noiseZ;
  params.relativeFloor = o.relativeFloor;
  params.indirectRadiance = o.margin * cached.brightestRadiance;
  const sma::MotionVolume volume = sma::MotionVolumes(before, after);
  t0 = Clock::now();
  const sma::MoveInvalidator invalidator(*old, volume, params);
  const double buildMs = 1e3 * Seconds(t0);

  // Selectivity and reasons, over the shaded points.
  size_t facing = 0, shaft = 0, cone = 0, invalidated = 0, direct = 0;
  std::vector<bool> isInvalidated(points.size());
  for (size_t i = 0; i < points.size(); ++i) {
    const sma::InvalidationVerdict v =
        invalidator.Judge({points[i].position, points[i].normal, cached.irradiance[i], cached.stdErr[i]});
    facing += v.facing;
    shaft += v.inLightShaft;
    cone += v.inSunCone;
    invalidated += v.invalidate;
    direct += v.invalidate && v.DirectlyInvalidated();
    isInvalidated[i] = v.invalidate;
  }
  const double n = double(points.size());
  {
    // How far above its tolerance each facing point's bound is: what a
    // bound tighter by a factor k would keep.
    std::vector<float> ratio;
    for (size_t i = 0; i < points.size(); ++i) {
      const sma::InvalidationVerdict v =
          invalidator.Judge({points[i].position, points[i].normal, cached.irradiance[i], cached.stdErr[i]});
      if (v.facing) ratio.push_back(v.tolerance > 0.0f ? v.changeBound / v.tolerance : 1e30f);
    }
    std::printf("bound / tolerance over the %zu facing points:", ratio.size());
    for (float k : {1.0f, 3.0f, 10.0f, 30.0f, 100.0f}) {
      const size_t above = size_t(std::count_if(ratio.begin(), ratio.end(), [&](float r) { return r > k; }));
      std::printf("  > %g: %.1f %%", double(k), 100.0 * double(above) / n);
    }
    std::printf(" (of all points)\n");
  }
  std::printf("motion volume: %u box(es); invalidator built in %.3f ms (%zu of %zu area-light triangles kept)\n",
              volume.count, buildMs, invalidator.RelevantLightCount(), old->emissiveTriangles.size());
  std::printf("invalidated %zu of %zu points (%.2f %%, %.1fx fewer than all), of which by direct light %zu "
              "(%.2f %%, %.1fx fewer); facing a box %.1f %%, in a light shaft %.2f %%, in the sun's cone %.2f %%\n",
              invalidated, points.size(), 100.0 * double(invalidated) / n, n / double(std::max<size_t>(invalidated, 1)),
              direct, 100.0 * double(direct) / n, n / double(std::max<size_t>(direct, 1)), 100.0 * double(facing) / n,
              100.0 * double(shaft) / n, 100.0 * double(cone) / n);

  // Speed: the shaded points repeated up to `timed` vertices.
  std::vector<Vec3> positions, normals;
  std::vector<float> irradiance, stdErr;
  for (int i = 0; i < o.timed; ++i) {
    const size_t k = size_t(i) % points.size();
    positions.push_back(points[k].position);
    normals.push_back(points[k].normal);
    irradiance.push_back(cached.irradiance[k]);
    stdErr.push_back(cached.stdErr[k]);
  }
  double bestSerial = 1e30, bestBulk = 1e30;
  size_t serialCount = 0, bulkCount = 0;
  for (int round = 0; round < 3; ++round) {
    t0 = Clock::now();
    serialCount = 0;
    for (size_t i = 0; i < positions.size(); ++i) {
      serialCount += invalidator.MayChange({positions[i], normals[i], irradiance[i], stdErr[i]});
    }
    bestSerial = std::min(bestSerial, Seconds(t0));
    t0 = Clock::now();
    auto bulk = invalidator.InvalidatedVertices({positions, normals, irradiance, stdErr});
    bestBulk = std::min(bestBulk, Seconds(t0));
    bulkCount = bulk->size();
  }
  std::printf("speed over %zu vertices (best of 3): one thread %.1f ns/vertex (%.1f ms); bulk helper, all threads "
              "%.1f ns/vertex (%.1f ms); %zu = %zu invalidated\n",
              positions.size(), 1e9 * bestSerial / double(positions.size()), 1e3 * bestSerial,
              1e9 * bestBulk / double(positions.size()), 1e3 * bestBulk, serialCount, bulkCount);

  std::vector<bool> surelyChanged;  // by the oracle, when it ran
  if (o.oracleSpp > 0) {
    t0 = Clock::now();
    // Two independent pairs, each pair with common random numbers.
    std::array<std::vector<float>, 2> change;
    for (int pair = 0; pair < 2; ++pair) {
      const uint64_t seed = uint64_t(2 + pair) << 30;
      const Shaded a = Shade(shader, atOld, points, o.oracleSpp, seed);
      const Shaded moved = Shade(shader, atNew, points, o.oracleSpp, seed);
      change[pair].resize(points.size());
      for (size_t i = 0; i < points.size(); ++i) change[pair][i] = moved.irradiance[i] - a.irradiance[i];
    }
    // A point needs re-shading when both pairs see it change by more than
    // tau ("surely"), or either does ("maybe": a rare path that found the
    // box in one pair only -- mostly black points, whose tau is 0). The
    // truth lies between the two counts.
    size_t surely = 0, maybe = 0, surelyDirect = 0, keptButSurely = 0, invalidatedNotMaybe = 0;
    for (size_t i = 0; i < points.size(); ++i) {
      const sma::InvalidationVerdict v =
          invalidator.Judge({points[i].position, points[i].normal, cached.irradiance[i], cached.stdErr[i]});
      const bool needA = std::abs(change[0][i]) > v.tolerance, needB = std::abs(change[1][i]) > v.tolerance;
      surely += needA && needB;
      maybe += needA || needB;
      surelyChanged.push_back(needA && needB);
      surelyDirect += needA && needB && v.invalidate && v.DirectlyInvalidated();
      invalidatedNotMaybe += v.invalidate && !(needA || needB);
      if (needA && needB && !v.invalidate && ++keptButSurely <= 10)
        std::printf("  kept but changed by more than tau: (%.3f %.3f %.3f) E %.4f, change %.4f / %.4f (two pairs), "
                    "tau %.4f, bound %.4f%s\n",
                    points[i].position.x, points[i].position.y, points[i].position.z, cached.irradiance[i],
                    change[0][i], change[1][i], v.tolerance, v.changeBound, v.facing ? "" : ", not facing the box");
    }
    std::printf("oracle (%d paths, common random numbers, 2 pairs, %.1f s): %zu points (%.2f %%) surely and %zu "
                "(%.2f %%) maybe change by more than their tolerance -- the best any invalidation at this tolerance "
                "could do is %.0f-%.0fx fewer than all (this one: %.1fx); of the sure ones %zu are in the direct class "
                "and %zu were kept; %zu invalidated that no pair saw change\n",
                o.oracleSpp, Seconds(t0), surely, 100.0 * double(surely) / n, maybe, 100.0 * double(maybe) / n,
                n / double(std::max<size_t>(maybe, 1)), n / double(std::max<size_t>(surely, 1)),
                n / double(std::max<size_t>(invalidated, 1)), surelyDirect, keptButSurely, invalidatedNotMaybe);
  }

  if (o.pairedPaths > 0) {
    // The design docs/moving-objects.md proposes for the indirect-only
    // class, tried on these points: instead of re-shading a candidate, test
    // it -- a few paths at both places with common random numbers, in 4
    // independent groups (their spread gives the change's standard error)
    // -- and keep it when |change| + z * standard error <= tau.
    std::vector<size_t> tested;
    std::vector<CachePoint> subset;
    std::vector<float> tolerance;
    for (size_t i = 0; i < points.size(); ++i) {
      const sma::InvalidationVerdict v =
          invalidator.Judge({points[i].position, points[i].normal, cached.irradiance[i], cached.stdErr[i]});
      if (!v.invalidate || v.DirectlyInvalidated()) continue;
      tested.push_back(i);
      subset.push_back(points[i]);
      tolerance.push_back(v.tolerance);
    }
    constexpr int kGroups = 4;
    const int perGroup = std::max(1, o.pairedPaths / kGroups);
    std::vector<std::array<float, kGroups>> change(subset.size());
    t0 = Clock::now();
    for (int g = 0; g < kGroups; ++g) {
      const uint64_t seed = uint64_t(6 + g) << 30;
      const Shaded atFirst = Shade(shader, atOld, subset, perGroup, seed);
      const Shaded moved = Shade(shader, atNew, subset, perGroup, seed);
      for (size_t j = 0; j < subset.size(); ++j) change[j][g] = moved.irradiance[j] - atFirst.irradiance[j];
    }
    size_t kept = 0, keptButSurely = 0;
    for (size_t j = 0; j < subset.size(); ++j) {
      float mean = 0.0f;
      for (float d : change[j]) mean += d / float(kGroups);
      float squares = 0.0f;
      for (float d : change[j]) squares += (d - mean) * (d - mean);
      const float standardError = std::sqrt(squares / float(kGroups - 1) / float(kGroups));
      if (std::abs(mean) + o.pairedZ * standardError > tolerance[j]) continue;
      ++kept;
      keptButSurely += !surelyChanged.empty() && surelyChanged[tested[j]];
    }
    const size_t reshaded = invalidated - kept;
    const double testPaths = double(subset.size()) * 2.0 * kGroups * perGroup;
    std::printf("paired test (%d paths at each place in %d groups, z %.1f, %.1f s): of %zu indirect-only candidates "
                "%zu kept, so %zu re-shaded (%.2f %%, %.1fx fewer than all); the tests cost %.0f paths, %.1f %% of "
                "re-shading every point at %d paths%s\n",
                kGroups * perGroup, kGroups, double(o.pairedZ), Seconds(t0), subset.size(), kept, reshaded,
                100.0 * double(reshaded) / n, n / double(std::max<size_t>(reshaded, 1)), testPaths,
                100.0 * testPaths / (n * double(o.spp)), o.spp,
                surelyChanged.empty()
                    ? ""
                    : fmt::format("; of the oracle's sure changes {} were kept", keptButSurely).c_str());
  }

  if (o.regionPaths > 0) {
    // The candidates tested by the renderer's first-order change estimate
    // (Shader::EstimateChangeThrough): the lights sampled on themselves and
    // every other path aimed through the motion volume's cones, each traced
    // at both places with common random numbers. A candidate is kept when
    // |change| + z * standard error <= tau. Two policies: test only the
    // indirect-only class (the direct class re-shaded as now), or test
    // every invalidated candidate.
    std::vector<size_t> tested;
    std::vector<bool> directClass;
    for (size_t i = 0; i < points.size(); ++i) {
      const sma::InvalidationVerdict v =
          invalidator.Judge({points[i].position, points[i].normal, cached.irradiance[i], cached.stdErr[i]});
      if (!v.invalidate) continue;
      tested.push_back(i);
      directClass.push_back(v.DirectlyInvalidated());
    }
    std::vector<ChangeEstimate> change(tested.size());
    std::vector<float> tolerance(tested.size());
    // The box at its two places: tighter than the motion volume's union.
    const std::array<Bounds3, 2> places{before, after};
    t0 = Clock::now();
    tbb::parallel_for(tbb::blocked_range<size_t>(0, tested.size(), 16), [&](const tbb::blocked_range<size_t>& r) {
      for (size_t j = r.begin(); j != r.end(); ++j) {
        const size_t i = tested[j];
        change[j] = shader.EstimateChangeThrough(atOld, atNew, InputOf(points[i], (uint64_t(11) << 30) + i),
                                                 places, o.regionPaths, nullptr);
        tolerance[j] = invalidator.Judge({points[i].position, points[i].normal, cached.irradiance[i], cached.stdErr[i]})
                           .tolerance;
      }
    });
    const double seconds = Seconds(t0);
    // The rule of three: a change no path saw is at most 3/n of the
    // region's solid angle times the largest radiance change (at 95 %).
    float largestRadianceChange = params.indirectRadiance;
    if (old->sky)
      largestRadianceChange += std::max({Luminance(old->sky->zenith), Luminance(old->sky->horizon),
                                         Luminance(old->sky->ground)});
    for (const int safe : {0, 1}) {
      size_t candidates = 0, kept = 0, keptButSurely = 0;
      for (size_t j = 0; j < tested.size(); ++j) {
        if (directClass[j]) continue;
        ++candidates;
        const float unseen = safe ? 3.0f / float(o.regionPaths) * largestRadianceChange * change[j].regionSolidAngle : 0.0f;
        if (std::abs(change[j].irradianceChange) + o.regionZ * change[j].standardError + unseen > tolerance[j]) continue;
        ++kept;
        keptButSurely += !surelyChanged.empty() && surelyChanged[tested[j]];
      }
      const size_t reshaded = invalidated - kept;
      std::printf("region test of the indirect-only class, %s: %zu of %zu kept, %zu re-shaded (%.1fx fewer than all)%s\n",
                  safe ? "with the rule of three's bound on unseen change" : "mean and spread only", kept, candidates,
                  reshaded, n / double(std::max<size_t>(reshaded, 1)),
                  surelyChanged.empty() ? "" : fmt::format("; {} sure changes kept", keptButSurely).c_str());
    }
    for (const bool testDirect : {false, true}) {
      size_t candidates = 0, kept = 0, keptButSurely = 0, firstOrderMisses = 0, noneThrough = 0;
      for (size_t j = 0; j < tested.size(); ++j) {
        if (directClass[j] && !testDirect) continue;
        ++candidates;
        noneThrough += change[j].pathsThroughRegion == 0;
        if (std::abs(change[j].irradianceChange) + o.regionZ * change[j].standardError > tolerance[j]) continue;
        ++kept;
        if (!surelyChanged.empty() && surelyChanged[tested[j]]) {
          ++keptButSurely;
          // What the first order is with far more paths: a change the test
          // missed (a rare path), or one it does not count (second order,
          // or the oracle's own noise).
          const size_t i = tested[j];
          const ChangeEstimate closer = shader.EstimateChangeThrough(
              atOld, atNew, InputOf(points[i], (uint64_t(12) << 30) + i), places, 16384, nullptr);
          if (std::abs(closer.irradianceChange) - 3.0f * closer.standardError <= tolerance[j]) continue;
          if (++firstOrderMisses <= 3)
            std::printf("  kept by the region test, but its first-order change exceeds tau: (%.3f %.3f %.3f) E %.4f, "
                        "tau %.4f, change %.4f +- %.4f%s; at 16384 paths %.4f +- %.4f\n",
                        points[i].position.x, points[i].position.y, points[i].position.z, cached.irradiance[i],
                        tolerance[j], change[j].irradianceChange, change[j].standardError,
                        directClass[j] ? " (direct class)" : "", closer.irradianceChange, closer.standardError);
        }
      }
      const size_t reshaded = invalidated - kept;
      const double testPaths = double(candidates) * 2.0 * o.regionPaths;
      std::printf("region test of %s (%d paired samples each, z %.1f; all tests %.1f s): of %zu candidates %zu kept "
                  "(%zu had no path through a box), so %zu re-shaded (%.2f %%, %.1fx fewer than all); the tests "
                  "cost %.0f paths, %.1f %% of re-shading every point at %d paths%s\n",
                  testDirect ? "every candidate" : "the indirect-only class", o.regionPaths, double(o.regionZ),
                  seconds, candidates, kept, noneThrough, reshaded, 100.0 * double(reshaded) / n,
                  n / double(std::max<size_t>(reshaded, 1)), testPaths, 100.0 * testPaths / (n * double(o.spp)),
                  o.spp,
                  surelyChanged.empty()
                      ? ""
                      : fmt::format("; of the oracle's sure changes {} were kept, {} of them with a first-order "
                                    "change beyond tau at 16384 paths",
                                    keptButSurely, firstOrderMisses)
                            .c_str());
    }
  }

  if (o.verify) {
    t0 = Clock::now();
    const Shaded fresh = Shade(shader, atNew, points, o.spp, 1u << 30);
    size_t changed = 0, missed = 0, changedNotDirect = 0;
    for (size_t i = 0; i < points.size(); ++i) {
      // Either estimate's own standard error can read 0 when its few paths
      // all missed a rare bright path; the larger of the two stands for both.
      const float sigma = std::sqrt(2.0f) * std::max(cached.stdErr[i], fresh.stdErr[i]);
      if (std::abs(fresh.irradiance[i] - cached.irradiance[i]) <= 4.0f * sigma + 1e-5f * cached.irradiance[i]) continue;
      ++changed;
      const sma::VertexSample s{points[i].position, points[i].normal, cached.irradiance[i], cached.stdErr[i]};
      changedNotDirect += !invalidator.Judge(s).DirectlyInvalidated();
      if (!isInvalidated[i]) {
        ++missed;
        const sma::InvalidationVerdict v =
            invalidator.Judge({points[i].position, points[i].normal, cached.irradiance[i], cached.stdErr[i]});
        std::printf("  kept but changed: (%.3f %.3f %.3f) E %.4f -> %.4f sigma %.4f bound %.4f tolerance %.4f\n",
                    points[i].position.x, points[i].position.y, points[i].position.z, cached.irradiance[i],
                    fresh.irradiance[i], sigma, v.changeBound, v.tolerance);
      }
    }
    std::printf("verify (re-shaded in %.1f s): %zu points changed beyond 4 sigma, %zu of them kept (missed), "
                "%zu not invalidated by direct light alone\n",
                Seconds(t0), changed, missed, changedNotDirect);
    return missed == 0 ? 0 : 2;
  }
  return 0;
}

}  // namespace
}  // namespace penumbra

int main(int argc, char** argv) {
  penumbra::Options o;
  CLI::App app{"Speed and selectivity of the SMA's move invalidation (motion volumes) on a real scene"};
  app.add_option("--scene", o.scene, "scene file (.json or a mesh)");
  app.add_option("--box-center", o.boxCenter, "centre of the moving box (x y z)")->expected(3);
  app.add_option("--box-size", o.boxSize, "side of the moving box, scene units")->check(CLI::PositiveNumber);
  app.add_option("--move", o.move, "the move (x y z)")->expected(3);
  app.add_option("--points", o.points, "static points shaded")->check(CLI::Range(1, 10000000));
  app.add_option("--spp", o.spp, "paths per point")->check(CLI::Range(1, 1 << 20));
  app.add_option("--timed", o.timed, "vertices in the timing runs")->check(CLI::Range(1, 100000000));
  app.add_flag("--verify", o.verify, "re-shade with the box moved and count changed points that were kept");
  app.add_option("--noise-z", o.noiseZ, "tolerance: standard errors")->check(CLI::NonNegativeNumber);
  app.add_option("--relative-floor", o.relativeFloor, "tolerance: fraction of E")->check(CLI::NonNegativeNumber);
  app.add_option("--margin", o.margin, "indirect bound: brightest cached radiance times this")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--oracle-spp", o.oracleSpp,
                 "also shade both places at this many paths with common random numbers: an ideal invalidation")
      ->check(CLI::Range(0, 1 << 20));
  app.add_option("--paired-test-paths", o.pairedPaths,
                 "test the indirect-only candidates with this many paired paths each instead of re-shading them")
      ->check(CLI::Range(0, 1 << 16));
  app.add_option("--paired-z", o.pairedZ, "paired test: standard errors of the change allowed under tau")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--region-test-paths", o.regionPaths,
                 "test the indirect-only candidates with this many paths through the motion volume each "
                 "(Shader::EstimateChangeThrough) instead of re-shading them")
      ->check(CLI::Range(0, 1 << 16));
  app.add_option("--region-z", o.regionZ, "region test: standard errors of the change allowed under tau")
      ->check(CLI::NonNegativeNumber);
  CLI11_PARSE(app, argc, argv);
  return penumbra::Run(o);
}
