#include "penumbra/sma/motion_volume.h"

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

namespace penumbra::sma {

namespace {

// Volume with each side at least 1 % of the longest, so that a flat box (a
// door, a floor tile) still has a volume to compare.
float RobustVolume(const Bounds3& b) {
  const Vec3 d = b.Diagonal();
  const float floor = 0.01f * std::max({d.x, d.y, d.z});
  return std::max(d.x, floor) * std::max(d.y, floor) * std::max(d.z, floor);
}

Bounds3 Union(const Bounds3& a, const Bounds3& b) {
  Bounds3 u;
  u.min = glm::min(a.min, b.min);
  u.max = glm::max(a.max, b.max);
  return u;
}

float MaxAbsDot(const Vec3& n, const Vec3& half) {
  return std::abs(n.x) * half.x + std::abs(n.y) * half.y + std::abs(n.z) * half.z;
}

// Solid angle of triangle (a, b, c) seen from the origin (Van Oosterom and
// Strackee 1983): tan(omega / 2) = |a . (b x c)| / (|a||b||c| + (a.b)|c| + (a.c)|b| + (b.c)|a|).
float TriangleSolidAngle(const Vec3& a, const Vec3& b, const Vec3& c) {
  const float la = glm::length(a), lb = glm::length(b), lc = glm::length(c);
  const float numerator = std::abs(glm::dot(a, glm::cross(b, c)));
  const float denominator = la * lb * lc + glm::dot(a, b) * lc + glm::dot(a, c) * lb + glm::dot(b, c) * la;
  return 2.0f * std::atan2(numerator, denominator);
}

// Upper bound on the cosine-weighted solid angle (projected solid angle) of a
// box seen from p on a surface with normal n: the solid angle of the box's
// bounding sphere times the largest cosine over that sphere's cap, at most
// pi (the whole hemisphere). Any radiance L arriving through the box changes
// the irradiance at p by at most L times this.
float ProjectedSolidAngleBound(const Vec3& p, const Vec3& n, const Vec3& center, float radius) {
  const Vec3 toCenter = center - p;
  const float d2 = glm::dot(toCenter, toCenter);
  const float r2 = radius * radius;
  if (d2 <= r2 * 1.0001f) return kPi;  // p inside (or on) the sphere: all of the hemisphere
  const float sin2Beta = r2 / d2;
  const float cosBeta = std::sqrt(1.0f - sin2Beta);
  const float solidAngle = 2.0f * kPi * (1.0f - cosBeta);
  const float d = std::sqrt(d2);
  const float cosTheta = std::clamp(glm::dot(n, toCenter) / d, -1.0f, 1.0f);
  // Largest cosine over the cap: cos(max(0, theta - beta)).
  float maxCos = 1.0f;
  if (cosTheta < cosBeta) {
    const float sinTheta = std::sqrt(std::max(0.0f, 1.0f - cosTheta * cosTheta));
    maxCos = std::max(0.0f, cosTheta * cosBeta + sinTheta * std::sqrt(sin2Beta));
  }
  return std::min(kPi, solidAngle * maxCos);
}

// The projected (cosine-weighted) solid angle of a convex planar polygon
// seen from p on a surface with normal n, over p's upper hemisphere only:
// the polygon is first clipped to the half-space n . (x - p) >= 0, then
// Lambert's formula gives it exactly,
//     integral of cos(theta) over the polygon's directions
//       = 1/2 |sum over edges (v_i, v_i+1) of angle(v_i, v_i+1) * n . unit(v_i x v_i+1)|
// (v_i relative to p; the irradiance from a polygon of radiance 1). A
// polygon whose plane contains p subtends nothing.
float PolygonProjectedSolidAngle(const Vec3& p, const Vec3& n, const std::array<Vec3, 4>& corners) {
  std::array<Vec3, 8> clipped{};  // a quad clipped by one plane has at most 5 corners
  size_t count = 0;
  for (size_t i = 0; i < corners.size(); ++i) {
    const Vec3 a = corners[i] - p;
    const Vec3 b = corners[(i + 1) % corners.size()] - p;
    const float heightA = glm::dot(n, a), heightB = glm::dot(n, b);
    if (heightA >= 0.0f) clipped[count++] = a;
    if ((heightA >= 0.0f) != (heightB >= 0.0f)) clipped[count++] = a + (heightA / (heightA - heightB)) * (b - a);
  }
  if (count < 3) return 0.0f;
  float sum = 0.0f;
  for (size_t i = 0; i < count; ++i) {
    const Vec3& a = clipped[i];
    const Vec3& b = clipped[(i + 1) % count];
    const Vec3 axb = glm::cross(a, b);
    const float sinTimesLengths = glm::length(axb);
    if (!(sinTimesLengths > 0.0f)) continue;  // a degenerate edge (a corner at p, or two equal corners)
    const float angle = std::atan2(sinTimesLengths, glm::dot(a, b));
    sum += angle * glm::dot(n, axb) / sinTimesLengths;
  }
  return 0.5f * std::abs(sum);
}

}  // namespace

float BoxProjectedSolidAngle(const Vec3& p, const Vec3& n, const Vec3& center, const Vec3& half) {
  const Vec3 local = p - center;
  if (std::abs(local.x) <= half.x && std::abs(local.y) <= half.y && std::abs(local.z) <= half.z) return kPi;
  // Seen from outside, the faces whose outer side faces p tile the box's
  // silhouette without overlapping (the box is convex): their sum is the
  // box's.
  float total = 0.0f;
  for (int axis = 0; axis < 3; ++axis) {
    const int u = (axis + 1) % 3, v = (axis + 2) % 3;
    for (const float side : {-1.0f, 1.0f}) {
      if (side * local[axis] <= half[axis]) continue;  // p is not in front of this face
      std::array<Vec3, 4> corners{};
      const std::array<std::array<float, 2>, 4> signs{{{-1.0f, -1.0f}, {1.0f, -1.0f}, {1.0f, 1.0f}, {-1.0f, 1.0f}}};
      for (size_t k = 0; k < 4; ++k) {
        Vec3 c = center;
        c[axis] += side * half[axis];
        c[u] += signs[k][0] * half[u];
        c[v] += signs[k][1] * half[v];
        corners[k] = c;
      }
      total += PolygonProjectedSolidAngle(p, n, corners);
    }
  }
  return std::min(kPi, total);
}

namespace {

// Whether the box (centre at the origin, half extents h) meets the
// tetrahedron v[0..3] (coordinates relative to the box centre): the
// separating axis theorem over the 3 box face normals, the 4 tetrahedron face
// normals and the 18 cross products of their edges. Exact for convex
// polyhedra; an axis too short to trust (parallel edges) is skipped, which
// can only report a meeting, never miss one.
bool BoxMeetsTetrahedron(const Vec3& h, const std::array<Vec3, 4>& v) {
  const auto separatedAlong = [&](const Vec3& axis) {
    const float r = MaxAbsDot(axis, h);
    float lo = glm::dot(axis, v[0]);
    float hi = lo;
    for (int i = 1; i < 4; ++i) {
      const float s = glm::dot(axis, v[i]);
      lo = std::min(lo, s);
      hi = std::max(hi, s);
    }
    return lo > r || hi < -r;
  };
  // Box faces: the tetrahedron's bounding box against the box.
  const Vec3 lo = glm::min(glm::min(v[0], v[1]), glm::min(v[2], v[3]));
  const Vec3 hi = glm::max(glm::max(v[0], v[1]), glm::max(v[2], v[3]));
  if (lo.x > h.x || lo.y > h.y || lo.z > h.z || hi.x < -h.x || hi.y < -h.y || hi.z < -h.z) return false;
  const std::array<Vec3, 6> edges{v[1] - v[0], v[2] - v[0], v[3] - v[0], v[2] - v[1], v[3] - v[1], v[3] - v[2]};
  // Tetrahedron faces (the light triangle first: it separates shafts that
  // pass behind the light cheaply).
  if (separatedAlong(glm::cross(edges[3], edges[4]))) return false;  // v1 v2 v3
  if (separatedAlong(glm::cross(edges[0], edges[1]))) return false;  // v0 v1 v2
  if (separatedAlong(glm::cross(edges[1], edges[2]))) return false;  // v0 v2 v3
  if (separatedAlong(glm::cross(edges[0], edges[2]))) return false;  // v0 v1 v3
  for (const Vec3& e : edges) {
    const float e2 = glm::dot(e, e);
    const float tiny = 1e-10f * e2;
    // cross(unit axis, e) for the box's x, y and z axes.
    const std::array<Vec3, 3> axes{Vec3(0.0f, -e.z, e.y), Vec3(e.z, 0.0f, -e.x), Vec3(-e.y, e.x, 0.0f)};
    for (const Vec3& axis : axes) {
      if (glm::dot(axis, axis) <= tiny) continue;
      if (separatedAlong(axis)) return false;
    }
  }
  return true;
}

// Whether the ray origin + t * direction, t >= 0, meets the box [lo, hi].
bool RayMeetsBox(const Vec3& origin, const Vec3& direction, const Vec3& lo, const Vec3& hi) {
  float tNear = 0.0f;
  float tFar = std::numeric_limits<float>::infinity();
  for (int axis = 0; axis < 3; ++axis) {
    const float o = origin[axis], d = direction[axis];
    if (std::abs(d) < 1e-12f) {
      if (o < lo[axis] || o > hi[axis]) return false;
      continue;
    }
    float t0 = (lo[axis] - o) / d;
    float t1 = (hi[axis] - o) / d;
    if (t0 > t1) std::swap(t0, t1);
    tNear = std::max(tNear, t0);
    tFar = std::min(tFar, t1);
    if (tNear > tFar) return false;
  }
  return true;
}

}  // namespace

MotionVolume MotionVolumes(const Bounds3& oldWorld, const Bounds3& newWorld, float mergeRatio) {
  MotionVolume volume;
  if (oldWorld.Empty() && newWorld.Empty()) return volume;
  if (oldWorld.Empty() || newWorld.Empty()) {
    volume.boxes[0] = oldWorld.Empty() ? newWorld : oldWorld;
    volume.count = 1;
    return volume;
  }
  const Bounds3 both = Union(oldWorld, newWorld);
  if (RobustVolume(both) <= mergeRatio * (RobustVolume(oldWorld) + RobustVolume(newWorld))) {
    volume.boxes[0] = both;
    volume.count = 1;
  } else {
    volume.boxes = {oldWorld, newWorld};
    volume.count = 2;
  }
  return volume;
}

MoveInvalidator::MoveInvalidator(const Scene& scene, const MotionVolume& volume, const InvalidationParams& params)
    : MoveInvalidator(scene, std::span<const MotionVolume>(&volume, 1), params) {}

MoveInvalidator::MoveInvalidator(const Scene& scene, std::span<const MotionVolume> volumes,
                                 const InvalidationParams& params)
    : params_(params) {
  std::vector<Bounds3> given;
  for (const MotionVolume& volume : volumes) {
    for (const Bounds3& b : volume.Boxes()) {
      if (!b.Empty()) given.push_back(b);
    }
  }
  if (given.size() > kMaxBoxes) {
    Bounds3 all;
    for (const Bounds3& b : given) all = Union(all, b);
    given.assign(1, all);
  }
  const float padding = params.padding >= 0.0f ? params.padding : 1e-4f * glm::length(scene.bounds.Diagonal());
  for (const Bounds3& b : given) {
    Box box;
    box.center = b.Center();
    box.half = 0.5f * b.Diagonal() + Vec3(padding);
    box.radius = glm::length(box.half);
    boxes_.push_back(box);
  }
  indirectRadiance_ = params.indirectRadiance >= 0.0f ? params.indirectRadiance : scene.MaxEmittedRadiance();

  // Area lights: only those with some box in front of their emitting face
  // can have a shaft through the volume (a shaft lies in front of its light).
  for (uint32_t t : scene.emissiveTriangles) {
    if (scene.ObjectOfTriangle(t) != kStaticObject) continue;  // Finalize forbids moving lights; be safe
    AreaLight light;
    for (int k = 0; k < 3; ++k) light.corner[k] = scene.Position(t, k);
    light.normal = scene.GeometricNormal(t);
    light.radiance = Luminance(scene.MaterialOf(t).emission);
    if (!(light.radiance > 0.0f) || !(scene.Area(t) > 0.0f)) continue;
    bool seesVolume = false;
    for (const Box& box : boxes_) {
      if (glm::dot(box.center - light.corner[0], light.normal) + MaxAbsDot(light.normal, box.half) > 0.0f) {
        seesVolume = true;
      }
    }
    if (!seesVolume) continue;
    lights_.push_back(light);
    lightRadianceSum_ += light.radiance;
  }
  if (scene.sun && Luminance(scene.sun->radiance) > 0.0f) {
    hasSun_ = true;
    sunDirection_ = glm::normalize(scene.sun->directionToSun);
    const float halfAngle = 0.5f * scene.sun->angularDiameterRad;
    sunTanHalfAngle_ = std::tan(halfAngle);
    sunSinHalfAngle_ = std::sin(halfAngle);
    sunSolidAngle_ = scene.sun->SolidAngle();
    sunRadiance_ = Luminance(scene.sun->radiance);
  }
  if (scene.sky) {
    // The sky's radiance interpolates between these three, so their largest
    // luminance bounds it in every direction.
    skyRadiance_ = std::max({Luminance(scene.sky->zenith), Luminance(scene.sky->horizon), Luminance(scene.sky->ground)});
  }
}

InvalidationVerdict MoveInvalidator::Judge(const VertexSample& v, bool complete) const {
  InvalidationVerdict verdict;
  verdict.tolerance = params_.Tolerance(v.irradiance, v.irradianceStdErr);
  const Vec3& p = v.position;
  const Vec3& n = v.normal;
  if (!IsFinite(p) || !IsFinite(n) || !std::isfinite(v.irradiance) || !std::isfinite(v.irradianceStdErr)) {
    // Nothing can be said about such a sample: re-shading it is the safe answer.
    verdict.facing = true;
    verdict.tolerance = 0.0f;
    verdict.changeBound = std::numeric_limits<float>::infinity();
    verdict.invalidate = true;
    return verdict;
  }

  // First reject: a box wholly behind the tangent plane sends nothing to p's
  // shaded side. Per box, its projected solid angle: first the cheap bound
  // of its bounding sphere; where even that, times every radiance that
  // could arrive through it, stays within tau, the vertex is kept at once
  // (most vertices of a large cache: the box is far). Otherwise the box's
  // exact projected solid angle (BoxProjectedSolidAngle, 1.4-2.5x below the
  // sphere's for a cube; raised by 0.1 % for float rounding) replaces it.
  // The decision is therefore the one the exact value alone would make,
  // whatever tau is (a tighter tau never invalidates fewer).
  std::array<float, kMaxBoxes> omega{};
  float omegaTotal = 0.0f;
  const size_t boxCount = boxes_.size();
  for (size_t b = 0; b < boxCount; ++b) {
    const Box& box = boxes_[b];
    if (glm::dot(box.center - p, n) + MaxAbsDot(n, box.half) <= 0.0f) continue;
    verdict.facing = true;
    omega[b] = ProjectedSolidAngleBound(p, n, box.center, box.radius);
    omegaTotal += omega[b];
  }
  if (!verdict.facing) return verdict;
  omegaTotal = std::min(omegaTotal, kPi);
  const float anyRadiance = indirectRadiance_ + skyRadiance_ + lightRadianceSum_ + (hasSun_ ? sunRadiance_ : 0.0f);
  if (anyRadiance * omegaTotal > verdict.tolerance) {
    omegaTotal = 0.0f;
    for (size_t b = 0; b < boxCount; ++b) {
      if (omega[b] <= 0.0f) continue;
      omega[b] = std::min(omega[b], 1.001f * BoxProjectedSolidAngle(p, n, boxes_[b].center, boxes_[b].half));
      omegaTotal += omega[b];
    }
    omegaTotal = std::min(omegaTotal, kPi);
  }

  // Indirect light and the sky: whatever arrives through the boxes.
  float bound = (indirectRadiance_ + skyRadiance_) * omegaTotal;
  // The sky is bounded like indirect light (every direction through the
  // boxes may reach it): only the area lights' and the sun's exact shaft
  // tests make up the direct class.
  const float solidAngleBound = bound;
  const auto decided = [&] { return !complete && bound > verdict.tolerance; };
  if (decided()) {
    verdict.changeBound = bound;
    verdict.directBound = bound - solidAngleBound;
    verdict.invalidate = true;
    return verdict;
  }

  // The sun: its cone from p (only when the sun is above p's tangent plane).
  if (hasSun_ && glm::dot(n, sunDirection_) > -sunSinHalfAngle_) {
    float omegaInCone = 0.0f;
    for (size_t b = 0; b < boxCount; ++b) {
      if (omega[b] <= 0.0f) continue;
      const Box& box = boxes_[b];
      // The cone's radius where it could meet the box is at most tFar *
      // tan(half angle); growing the box by that and testing the axis ray is
      // conservative and, for a sun's half-degree, tight.
      const float tFar = glm::length(box.center - p) + box.radius;
      const Vec3 grow(tFar * sunTanHalfAngle_);
      if (RayMeetsBox(p, sunDirection_, box.center - box.half - grow, box.center + box.half + grow)) {
        omegaInCone += omega[b];
      }
    }
    if (omegaInCone > 0.0f) {
      omegaInCone = std::min(omegaInCone, kPi);
      verdict.inSunCone = true;
      bound += sunRadiance_ * std::min(sunSolidAngle_, omegaInCone);
      if (decided()) {
        verdict.changeBound = bound;
        verdict.directBound = bound - solidAngleBound;
        verdict.invalidate = true;
        return verdict;
      }
    }
  }

  // Area lights. The change from light l is at most its radiance times the
  // smaller of its solid angle and the boxes' in its shaft. Skip the shaft
  // tests when even every light at full strength could not pass tau.
  if (!lights_.empty() && (complete || bound + lightRadianceSum_ * omegaTotal > verdict.tolerance)) {
    float remaining = lightRadianceSum_ * omegaTotal;  // what the lights not yet looked at could add
    for (const AreaLight& light : lights_) {
      remaining -= light.radiance * omegaTotal;
      // The light emits from its front face only, and must rise above p's
      // tangent plane somewhere.
      if (glm::dot(p - light.corner[0], light.normal) <= 0.0f) continue;
      const float aboveTangent = std::max({glm::dot(light.corner[0] - p, n), glm::dot(light.corner[1] - p, n),
                                           glm::dot(light.corner[2] - p, n)});
      if (aboveTangent <= 0.0f) continue;
      float omegaInShaft = 0.0f;
      for (size_t b = 0; b < boxCount; ++b) {
        if (omega[b] <= 0.0f) continue;
        const Box& box = boxes_[b];
        const std::array<Vec3, 4> tetrahedron{p - box.center, light.corner[0] - box.center,
                                              light.corner[1] - box.center, light.corner[2] - box.center};
        if (BoxMeetsTetrahedron(box.half, tetrahedron)) omegaInShaft += omega[b];
      }
      if (omegaInShaft > 0.0f) {
        omegaInShaft = std::min(omegaInShaft, kPi);
        verdict.inLightShaft = true;
        const float omegaLight = TriangleSolidAngle(light.corner[0] - p, light.corner[1] - p, light.corner[2] - p);
        bound += light.radiance * std::min(omegaLight, omegaInShaft);
        if (decided()) break;
      }
      if (!complete && bound + std::max(0.0f, remaining) <= verdict.tolerance) break;  // cannot pass tau any more
    }
  }
  verdict.changeBound = bound;
  verdict.directBound = bound - solidAngleBound;
  verdict.invalidate = bound > verdict.tolerance;
  return verdict;
}

namespace {

Status CheckSpans(const VertexSpans& vertices) {
  const size_t count = vertices.positions.size();
  if (vertices.normals.size() != count || vertices.irradiance.size() != count ||
      vertices.irradianceStdErr.size() != count) {
    return Fail(fmt::format("InvalidatedVertices: spans of unequal length (positions {}, normals {}, irradiance {}, "
                            "irradiance standard errors {})",
                            count, vertices.normals.size(), vertices.irradiance.size(),
                            vertices.irradianceStdErr.size()));
  }
  if (count > std::numeric_limits<uint32_t>::max()) return Fail("InvalidatedVertices: more than 2^32 vertices");
  return Status::Ok();
}

enum : uint8_t { kKept = 0, kIndirectOnly = 1, kDirect = 2 };

// One flag per vertex written in parallel (then gathered in order by the
// caller: the result does not depend on how TBB split the work).
template <class Decide>
std::vector<uint8_t> FlagAll(const VertexSpans& vertices, const Decide& decide) {
  std::vector<uint8_t> flags(vertices.positions.size(), kKept);
  tbb::parallel_for(tbb::blocked_range<size_t>(0, flags.size(), 4096), [&](const tbb::blocked_range<size_t>& range) {
    for (size_t i = range.begin(); i != range.end(); ++i) {
      flags[i] = decide(VertexSample{vertices.positions[i], vertices.normals[i], vertices.irradiance[i],
                                     vertices.irradianceStdErr[i]});
    }
  });
  return flags;
}

}  // namespace

Expected<std::vector<uint32_t>> MoveInvalidator::InvalidatedVertices(const VertexSpans& vertices) const {
  if (Status ok = CheckSpans(vertices); !ok) return ok.error();
  const std::vector<uint8_t> flags =
      FlagAll(vertices, [&](const VertexSample& v) { return MayChange(v) ? kDirect : kKept; });
  std::vector<uint32_t> indices;
  for (size_t i = 0; i < flags.size(); ++i) {
    if (flags[i] != kKept) indices.push_back(static_cast<uint32_t>(i));
  }
  return indices;
}

Expected<InvalidatedSet> MoveInvalidator::ClassifyInvalidated(const VertexSpans& vertices) const {
  if (Status ok = CheckSpans(vertices); !ok) return ok.error();
  const std::vector<uint8_t> flags = FlagAll(vertices, [&](const VertexSample& v) -> uint8_t {
    if (!MayChange(v)) return kKept;
    return Judge(v, /*complete=*/true).DirectlyInvalidated() ? kDirect : kIndirectOnly;
  });
  InvalidatedSet set;
  for (size_t i = 0; i < flags.size(); ++i) {
    if (flags[i] == kDirect) set.direct.push_back(static_cast<uint32_t>(i));
    if (flags[i] == kIndirectOnly) set.indirectOnly.push_back(static_cast<uint32_t>(i));
  }
  return set;
}

}  // namespace penumbra::sma
