// Path tracer for vertex samples; the contract is in shading.h.
//
// Estimator. `throughput` is the factor that turns an estimate of the
// cosine-weighted incident integral at the current path vertex into its
// contribution to E at the sample. It starts at 1 (E itself has no albedo);
// a cosine-sampled bounce contributes L_in * pi (cos / pdf), and the next
// vertex's integral enters through albedo / pi, so each bounce multiplies the
// throughput by the albedo it meets.
//
// Speed. A path is a loop of single Embree queries; what surrounds them reads
// compact tables built once -- 4 bytes per triangle (its material; Embree
// returns the normal), and the lights with their geometry and an alias table
// -- so a bounce costs one small fetch besides the ray (plus the texel, for
// a textured surface), and a light sample touches nothing outside the
// (usually cache-resident) light table.

#include "penumbra/renderer/shading.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <iterator>
#include <limits>
#include <optional>
#include <vector>

#include <fmt/format.h>

#include "penumbra/common/rng.h"
#include "penumbra/renderer/ray_scene.h"
#include "sampling.h"

namespace penumbra {

namespace {

constexpr float kInfinity = std::numeric_limits<float>::infinity();

// Ray origins move off surfaces by this fraction of the scene's largest
// coordinate: float rounding in hit points and in Embree's plane test grows
// with the coordinates (one ulp is 1.2e-7 of them), and 1e-5 keeps ~80 ulps
// of margin while staying far below any feature worth shading.
constexpr float kRelativeOffset = 1e-5f;

// A sample is enclosed when nearly every direction meets a surface within
// this fraction of the way from it to the inside of its triangle: much
// nearer than the surface it stands for extends (header: "Buried samples").
constexpr float kEnclosureReach = 1.0f / 8.0f;

float MaxComponent(const Rgb& c) { return std::max({c.r, c.g, c.b}); }

float LargestCoordinate(const Bounds3& b) {
  const Vec3 m = glm::max(glm::abs(b.min), glm::abs(b.max));
  return std::max({m.x, m.y, m.z});
}

}  // namespace

// The path tracer's own types, which Shader::Impl holds: in a named
// namespace, not the anonymous one -- a member of a type with external
// linkage must not use a type of it (gcc's -Wsubobject-linkage, which a
// unity build, #including this file, reports).
namespace shading_detail {

// An emissive triangle, with what sampling it needs.
struct Light {
  Vec3 p0, edge1, edge2;  // p = p0 + b1 edge1 + b2 edge2
  Vec3 normal;            // unit, the emitting (front) side
  Rgb emission;
  float pdfArea = 0.0f;  // P(choose this light) / area
};

// A point paths leave from: the ray origin (already off the surface), the
// frame of the normal that weights incident light (z), and the geometric
// normal of its triangle on the same side (below which nothing arrives).
struct PathVertex {
  Vec3 origin;
  Frame frame;
  Vec3 geometricNormal;
  float offset = 0.0f;  // how far the origin was moved off its surface (Shader::Impl::OffsetAt)
};

}  // namespace shading_detail

using shading_detail::Light;
using shading_detail::PathVertex;

// --- Validation -------------------------------------------------------------

Status ValidateShadeInput(const Scene& scene, const ShadeInput& in) {
  return ValidateShadeInput(scene, ScenePose::Initial(scene), in);
}

Status ValidateShadeInput(const Scene& scene, const ScenePose& pose, const ShadeInput& in) {
  if (!IsFinite(in.position))
    return Fail(fmt::format("position ({}, {}, {}) is not finite", in.position.x, in.position.y, in.position.z));
  if (!IsFinite(in.normal))
    return Fail(fmt::format("normal ({}, {}, {}) is not finite", in.normal.x, in.normal.y, in.normal.z));
  if (!std::isfinite(in.b1) || !std::isfinite(in.b2))
    return Fail(fmt::format("barycentrics ({}, {}) are not finite", in.b1, in.b2));
  const float normalLength = glm::length(in.normal);
  if (std::abs(normalLength - 1.0f) > 1e-2f)
    return Fail(fmt::format("normal ({}, {}, {}) has length {}, not 1", in.normal.x, in.normal.y,
                            in.normal.z, normalLength));
  if (in.triangle >= scene.triangles.size())
    return Fail(fmt::format("triangle {} is out of range (the scene has {})", in.triangle, scene.triangles.size()));
  constexpr float kBarycentricSlack = 1e-3f;
  if (in.b1 < -kBarycentricSlack || in.b2 < -kBarycentricSlack || in.b1 + in.b2 > 1.0f + kBarycentricSlack)
    return Fail(fmt::format("barycentrics ({}, {}) are outside triangle {}", in.b1, in.b2, in.triangle));
  const Vec3 expected = WorldPointAt(scene, pose, in.triangle, in.b1, in.b2);
  // An object moved far from the scene has coordinates whose rounding can
  // exceed a tolerance relative to the scene's size.
  const float tolerance = std::max(1e-4f * glm::length(scene.bounds.Diagonal()),
                                   1e-6f * std::max({std::abs(expected.x), std::abs(expected.y), std::abs(expected.z)}));
  const float distance = glm::length(in.position - expected);
  if (!(distance <= tolerance))
    return Fail(fmt::format("position ({}, {}, {}) is {} away from triangle {} at barycentrics ({}, {}) "
                            "(tolerance {})",
                            in.position.x, in.position.y, in.position.z, distance, in.triangle, in.b1, in.b2,
                            tolerance));
  return Status::Ok();
}

// --- The path tracer ----------------------------------------------------------

struct Shader::Impl {
  Impl(const Scene& s, const RayScene& r, ShadingSettings ss);

  // Where a sample's paths leave from (ray origin, frames), and on which
  // side of its triangle it is: the header's "Geometry" and "Buried samples".
  PathVertex SampleStart(const PosedRayScene& at, const ShadeInput& in, Pcg32& rng, ShadeCounters& counters,
                         bool* frontSide) const;
  // Radiance arriving at `origin` from `direction`, one path: a light's
  // emission (with the density light sampling from `origin` would have
  // chosen that point with, for the caller's MIS weight), and the sky and
  // the hit's reflected light (TracePath).
  struct Incident {
    Rgb emitted{0.0f};
    float lightPdf = 0.0f;  // solid angle; 0: not an emitter's front
    Rgb skyAndReflected{0.0f};
  };
  Incident IncidentRadiance(const PosedRayScene& at, const Vec3& origin, const Vec3& direction, Pcg32& rng,
                            ShadeCounters& counters) const;
  // The numbers a path draws at its first vertex, given from outside so
  // that the paths of one estimate can be stratified (Shade): the direction
  // it leaves in (cosine-weighted), the sun's direction in its cone, and the
  // area light and the point on it.
  struct FirstVertexNumbers {
    Vec2 direction{0.0f};
    Vec2 inSunCone{0.0f};
    float lightChoice = 0.0f;
    Vec2 onLight{0.0f};
  };
  // Irradiance estimate of one path from `start`.
  // `firstSegment` > 0: the path continues one that already has that many
  // segments (the caps on segments and Russian roulette count them).
  // `first`: the numbers of its first vertex (else drawn from `rng`).
  Rgb TracePath(const PosedRayScene& at, const PathVertex& start, Pcg32& rng, ShadeCounters& counters,
                int firstSegment = 0, const FirstVertexNumbers* first = nullptr) const;
  // Next-event estimates at `v` (throughput not applied), one shadow ray
  // each; the area light's MIS-weighted against cosine sampling.
  // (The point on the light and the sun's direction take their two numbers
  // in the order of the draws that were once the unsequenced arguments of
  // the warp, as GCC evaluated them -- last first --, so that every sample's
  // estimate stays what it has been.)
  Rgb SampleAreaLight(const PosedRayScene& at, const PathVertex& v, Pcg32& rng, ShadeCounters& counters) const {
    const float u0 = rng.NextFloat(), u1 = rng.NextFloat();
    const float u3 = rng.NextFloat(), u2 = rng.NextFloat();
    return SampleAreaLight(at, v, {u0, u1, u2, u3}, counters);
  }
  Rgb SampleSun(const PosedRayScene& at, const PathVertex& v, Pcg32& rng, ShadeCounters& counters) const {
    const float u1 = rng.NextFloat(), u0 = rng.NextFloat();
    return SampleSun(at, v, Vec2(u0, u1), counters);
  }
  // The same from given uniform numbers: u[0], u[1] choose the light, u[2],
  // u[3] the point on it (the sun: the direction in its cone).
  Rgb SampleAreaLight(const PosedRayScene& at, const PathVertex& v, const std::array<float, 4>& u,
                      ShadeCounters& counters) const;
  // A point on the area lights seen from `v` (no shadow ray): its direction
  // and distance, its emission, and the solid-angle density of choosing it
  // (pdf 0: it faces away or lies below v's surface -- it brings nothing).
  struct LightPoint {
    Vec3 direction{0.0f};
    float distance = 0.0f;
    float cosAtVertex = 0.0f;
    Rgb emission{0.0f};
    float pdf = 0.0f;
  };
  LightPoint SampleLightPoint(const PathVertex& v, const std::array<float, 4>& u) const;
  Rgb SampleSun(const PosedRayScene& at, const PathVertex& v, const Vec2& u, ShadeCounters& counters) const;
  // Where to shade a sample leaving from `start` (header: "Buried samples");
  // `inside` is a point off the same side of the sample's triangle, well inside it.
  Vec3 UnburiedOrigin(const PosedRayScene& at, const PathVertex& start, const Vec3& inside, Pcg32& rng,
                      ShadeCounters& counters) const;
  // Whether nearly every direction of `start`'s hemisphere from `origin`
  // meets a surface within `reach` (header: "Buried samples").
  bool Enclosed(const PosedRayScene& at, const PathVertex& start, const Vec3& origin, float reach, Pcg32& rng,
                ShadeCounters& counters) const;
  // How far a ray origin at `p` moves off its surface: `offset`, unless p
  // lies on a movable object taken beyond twice the scene's reach, whose
  // coordinates' rounding needs an offset relative to its own. Static points
  // always get `offset` (they lie within the scene's bounds), so a client
  // moving an object far out changes nothing for the rest of the scene.
  float OffsetAt(const Vec3& p) const {
    const float reach = std::max({std::abs(p.x), std::abs(p.y), std::abs(p.z)});
    return reach <= 2.0f * largestCoordinate ? offset : kRelativeOffset * reach;
  }

  const Scene& scene;
  const RayScene& rays;
  const ShadingSettings settings;
  std::vector<uint32_t> materialOf;  // per triangle: a denser copy of Triangle::material
  // Lights are chosen in proportion to their power, Luminance(Le) * area, so
  // the density of a point on light i is Luminance(Le_i) / totalPower.
  std::vector<Light> lights;
  sampling::AliasTable lightSelection;
  float inverseTotalPower = 0.0f;
  // The sun's cone, when the scene has a sun.
  Frame sunFrame{};  // z toward the sun's centre
  float sunCosHalfAngle = 1.0f;
  float sunSolidAngle = 0.0f;
  float largestCoordinate = 0.0f;  // of the scene's bounds as loaded
  float offset = 0.0f;             // how far ray origins are moved off the surface they leave
};

Shader::Impl::Impl(const Scene& s, const RayScene& r, ShadingSettings ss)
    : scene(s), rays(r), settings(ss), materialOf(s.triangles.size()) {
  for (uint32_t t = 0; t < s.triangles.size(); ++t) materialOf[t] = s.triangles[t].material;

  std::vector<double> power;
  for (uint32_t t : s.emissiveTriangles) {
    const Material& m = s.MaterialOf(t);
    const double p = double(Luminance(m.emission)) * double(s.Area(t));
    if (!(p > 0.0)) continue;  // no area: never hit, never worth sampling
    const Vec3& p0 = s.Position(t, 0);
    lights.push_back(Light{p0, s.Position(t, 1) - p0, s.Position(t, 2) - p0, s.GeometricNormal(t), m.emission, 0.0f});
    power.push_back(p);
  }
  if (!lights.empty()) {
    double totalPower = 0.0;
    for (double p : power) totalPower += p;
    inverseTotalPower = float(1.0 / totalPower);
    for (Light& light : lights) light.pdfArea = Luminance(light.emission) * inverseTotalPower;
    lightSelection = sampling::AliasTable(power);
  }

  if (s.sun) {
    sunFrame = Frame::FromNormal(s.sun->directionToSun);
    sunCosHalfAngle = s.sun->CosHalfAngle();
    sunSolidAngle = s.sun->SolidAngle();
  }
  largestCoordinate = LargestCoordinate(s.bounds);
  offset = kRelativeOffset * largestCoordinate;
}

Rgb Shader::Impl::TracePath(const PosedRayScene& at, const PathVertex& start, Pcg32& rng,
                            ShadeCounters& counters, int firstSegment, const FirstVertexNumbers* first) const {
  PathVertex v = start;
  Rgb throughput(1.0f);
  Rgb irradiance(0.0f);
  const int maxSegments = settings.MaxSegments();
  for (int depth = firstSegment; depth < maxSegments; ++depth) {
    const bool given = first != nullptr && depth == firstSegment;
    if (!lights.empty())
      irradiance += throughput * (given ? SampleAreaLight(at, v,
                                                          {first->lightChoice, rng.NextFloat(), first->onLight.x,
                                                           first->onLight.y},
                                                          counters)
                                        : SampleAreaLight(at, v, rng, counters));
    if (scene.sun)
      irradiance += throughput * (given ? SampleSun(at, v, first->inSunCone, counters) : SampleSun(at, v, rng, counters));

    Vec3 local;
    if (given) {
      local = sampling::CosineHemisphere(first->direction.x, first->direction.y);
    } else {
      // (The second number first: the order GCC evaluated the call's
      // arguments in when they were draws, kept so that paths past the
      // first vertex trace what they always have.)
      const float u2 = rng.NextFloat(), u1 = rng.NextFloat();
      local = sampling::CosineHemisphere(u1, u2);
    }
    const Vec3 direction = v.frame.ToWorld(local);
    if (glm::dot(direction, v.geometricNormal) <= 0.0f) break;  // into the surface itself
    ++counters.rays;
    const std::optional<RayHit> hit = at.Intersect(v.origin, direction, 0.0f, kInfinity);
    // Cosine-weighted incident radiance over the cosine pdf: a factor pi.
    if (!hit) {
      if (scene.sky) irradiance += throughput * kPi * scene.sky->Radiance(direction);
      break;
    }
    const Vec3 hitNormal = glm::normalize(hit->normal);
    const Material& material = scene.materials[materialOf[hit->triangle]];
    const float cosAtHit = glm::dot(hitNormal, direction);  // < 0: the front face was hit
    if (cosAtHit < 0.0f && material.IsEmissive()) {
      // The light sample at `v` could have produced this point too.
      const float pdfLight = Luminance(material.emission) * inverseTotalPower * hit->t * hit->t / -cosAtHit;
      const float weight = sampling::PowerHeuristic(sampling::CosineHemispherePdf(local.z), pdfLight);
      irradiance += throughput * kPi * weight * material.emission;
    }
    if (depth + 1 == maxSegments) break;

    // Only a textured albedo needs the hit's texture coordinates.
    const Rgb albedo =
        material.albedoTexture < 0 ? material.albedo : scene.AlbedoAt(hit->triangle, hit->b1, hit->b2);
    throughput *= albedo;
    if (depth + 1 >= settings.russianRouletteDepth) {
      // Survival in proportion to the albedo: in a uniform scene the
      // throughput then stays constant instead of decaying.
      const float survival = std::min(1.0f, MaxComponent(albedo));
      if (rng.NextFloat() >= survival) break;
      throughput /= survival;
    }
    if (MaxComponent(throughput) <= 0.0f) break;

    // Both sides reflect: shade the side the path arrived from. The hit
    // point comes from the ray rather than the barycentrics: no vertex
    // fetches, and its rounding error (ulps of the coordinates) is far below
    // the offset.
    v.geometricNormal = cosAtHit < 0.0f ? hitNormal : -hitNormal;
    v.frame = Frame::FromNormal(v.geometricNormal);
    const Vec3 hitPoint = v.origin + hit->t * direction;
    v.offset = OffsetAt(hitPoint);
    v.origin = hitPoint + v.offset * v.geometricNormal;
  }
  return irradiance;
}

Shader::Impl::LightPoint Shader::Impl::SampleLightPoint(const PathVertex& v, const std::array<float, 4>& u) const {
  const Light& light = lights[lightSelection.Sample(u[0], u[1])];
  const Vec2 b = sampling::UniformTriangle(u[2], u[3]);
  const Vec3 onLight = light.p0 + b.x * light.edge1 + b.y * light.edge2;

  LightPoint out;
  const Vec3 toLight = onLight - v.origin;
  const float distance2 = glm::dot(toLight, toLight);
  out.distance = std::sqrt(distance2);
  out.direction = toLight / out.distance;
  out.cosAtVertex = glm::dot(out.direction, v.frame.n);
  const float cosAtLight = -glm::dot(out.direction, light.normal);  // emitters emit from the front only
  if (out.cosAtVertex <= 0.0f || cosAtLight <= 0.0f || glm::dot(out.direction, v.geometricNormal) <= 0.0f)
    return out;
  out.emission = light.emission;
  out.pdf = light.pdfArea * distance2 / cosAtLight;
  return out;
}

Rgb Shader::Impl::SampleAreaLight(const PosedRayScene& at, const PathVertex& v, const std::array<float, 4>& u,
                                  ShadeCounters& counters) const {
  const LightPoint light = SampleLightPoint(v, u);
  if (!(light.pdf > 0.0f)) return Rgb(0.0f);
  ++counters.rays;
  ++counters.shadowRays;
  // Stop short of the light so that its own surface does not occlude it.
  if (at.Occluded(v.origin, light.direction, 0.0f, light.distance - v.offset)) return Rgb(0.0f);
  const float weight = sampling::PowerHeuristic(light.pdf, sampling::CosineHemispherePdf(light.cosAtVertex));
  return light.emission * (weight * light.cosAtVertex / light.pdf);
}

Vec3 Shader::Impl::UnburiedOrigin(const PosedRayScene& at, const PathVertex& start, const Vec3& inside, Pcg32& rng,
                                  ShadeCounters& counters) const {
  const float offset = start.offset;
  const Vec3 toSample = start.origin - inside;
  const float distance = glm::length(toSample);
  if (!(distance > 4.0f * offset)) return start.origin;
  const Vec3 along = toSample / distance;
  const float backOff = std::max(4.0f * offset, 0.01f * distance);

  // Inside a solid: the way from the inside point enters it through a front
  // face, and from the sample nearly nothing but its inside is seen.
  ++counters.rays;
  const std::optional<RayHit> entry = at.Intersect(inside, along, 0.0f, distance);
  if (entry && glm::dot(entry->normal, along) < 0.0f) {
    constexpr int kProbes = 16;
    const bool openSky = scene.sky.has_value() || scene.sun.has_value();
    int seesOut = 0;
    for (int i = 0; i < kProbes; ++i) {
      const Vec3 direction = start.frame.ToWorld(sampling::CosineHemisphere(rng.NextFloat(), rng.NextFloat()));
      ++counters.rays;
      const std::optional<RayHit> hit = at.Intersect(start.origin, direction, 0.0f, kInfinity);
      if (hit ? glm::dot(hit->normal, direction) < 0.0f : openSky) ++seesOut;
    }
    if (seesOut * 10 <= kProbes) {
      ++counters.buriedSamples;
      return inside + std::max(0.0f, entry->t - backOff) * along;
    }
  }

  // Enclosed, whatever the facing: nearly every direction meets a surface
  // within an eighth of the way to the inside point -- a thin cavity between
  // a wall and the cornice or skirting laid over it, the inside of an
  // inward-wound or open-backed solid. Shade the nearest point on the way to
  // the inside point that sees past the surface the sample stands for
  // (more than one probe in 16 goes further than the inside point): just
  // past each surface the way crosses, else at growing fractions of the way.
  // (Open merely at the eighth, a point may still be inside a cornice.)
  if (!Enclosed(at, start, start.origin, kEnclosureReach * distance, rng, counters)) return start.origin;
  constexpr int kMaxCrossings = 4;
  constexpr float kFractions[] = {1.0f / 16.0f, 1.0f / 8.0f, 1.0f / 4.0f, 1.0f / 2.0f, 1.0f};
  std::array<float, kMaxCrossings + std::size(kFractions)> candidates{};
  size_t count = 0;
  for (float t = 0.0f; count < kMaxCrossings;) {
    ++counters.rays;
    const std::optional<RayHit> crossing = at.Intersect(start.origin, -along, t, distance);
    if (!crossing) break;
    t = crossing->t + backOff;
    if (t < distance) candidates[count++] = t;
  }
  for (float f : kFractions) candidates[count++] = f * distance;
  std::sort(candidates.begin(), candidates.begin() + ptrdiff_t(count));
  for (size_t i = 0; i < count; ++i) {
    const Vec3 candidate = start.origin - candidates[i] * along;
    if (Enclosed(at, start, candidate, distance, rng, counters)) continue;
    ++counters.buriedSamples;
    return candidate;
  }
  return start.origin;  // its whole way is enclosed: nothing better to shade
}

bool Shader::Impl::Enclosed(const PosedRayScene& at, const PathVertex& start, const Vec3& origin, float reach,
                            Pcg32& rng, ShadeCounters& counters) const {
  constexpr int kProbes = 16;
  constexpr int kMaxOpen = 1;  // of kProbes: "nearly every direction" is 15 of 16
  int open = 0;
  for (int i = 0; i < kProbes; ++i) {
    const Vec3 direction = start.frame.ToWorld(sampling::CosineHemisphere(rng.NextFloat(), rng.NextFloat()));
    if (glm::dot(direction, start.geometricNormal) <= 0.0f) continue;  // into its own surface
    ++counters.rays;
    ++counters.shadowRays;
    if (!at.Occluded(origin, direction, 0.0f, reach) && ++open > kMaxOpen) return false;
  }
  return true;
}

Rgb Shader::Impl::SampleSun(const PosedRayScene& at, const PathVertex& v, const Vec2& u,
                            ShadeCounters& counters) const {
  const Vec3 direction = sunFrame.ToWorld(sampling::UniformCone(u.x, u.y, sunCosHalfAngle));
  const float cosAtVertex = glm::dot(direction, v.frame.n);
  if (cosAtVertex <= 0.0f || glm::dot(direction, v.geometricNormal) <= 0.0f) return Rgb(0.0f);
  ++counters.rays;
  ++counters.shadowRays;
  if (at.Occluded(v.origin, direction, 0.0f, kInfinity)) return Rgb(0.0f);
  // Uniform over the cone: radiance * cos / (1 / solid angle).
  return scene.sun->radiance * (cosAtVertex * sunSolidAngle);
}

PathVertex Shader::Impl::SampleStart(const PosedRayScene& at, const ShadeInput& in, Pcg32& rng,
                                      ShadeCounters& counters, bool* frontSide) const {
  const float sampleOffset = OffsetAt(in.position);
  const Vec3 normal = glm::normalize(in.normal);
  // The sample's triangle where the pose puts it (a movable object's
  // vertices are stored in its own space).
  const Vec3 faceNormal = WorldGeometricNormal(scene, at.Pose(), in.triangle);
  *frontSide = glm::dot(normal, faceNormal) >= 0.0f;

  PathVertex start;
  start.frame = Frame::FromNormal(normal);
  start.geometricNormal = *frontSide ? faceNormal : -faceNormal;
  start.offset = sampleOffset;
  // Off the surface along the normal, and into the triangle toward its
  // centroid (no further than halfway), so that a neighbour meeting this
  // vertex or edge at an angle -- a wall at the edge of a floor -- lies
  // clearly on one side of the origin.
  const Vec3 centroid = WorldPointAt(scene, at.Pose(), in.triangle, 1.0f / 3.0f, 1.0f / 3.0f);
  const Vec3 toCentroid = centroid - in.position;
  const float toCentroidLength = glm::length(toCentroid);
  start.origin = in.position + sampleOffset * start.geometricNormal;
  if (toCentroidLength > 0.0f)
    start.origin += toCentroid * (std::min(sampleOffset, 0.5f * toCentroidLength) / toCentroidLength);
  start.origin = UnburiedOrigin(at, start, centroid + sampleOffset * start.geometricNormal, rng, counters);
  return start;
}

Shader::Impl::Incident Shader::Impl::IncidentRadiance(const PosedRayScene& at, const Vec3& origin,
                                                      const Vec3& direction, Pcg32& rng,
                                                      ShadeCounters& counters) const {
  Incident out;
  ++counters.rays;
  const std::optional<RayHit> hit = at.Intersect(origin, direction, 0.0f, kInfinity);
  if (!hit) {
    if (scene.sky) out.skyAndReflected = scene.sky->Radiance(direction);
    return out;
  }
  const Vec3 hitNormal = glm::normalize(hit->normal);
  const Material& material = scene.materials[materialOf[hit->triangle]];
  const float cosAtHit = glm::dot(hitNormal, direction);
  if (cosAtHit < 0.0f && material.IsEmissive() && !lights.empty()) {
    out.emitted = material.emission;
    out.lightPdf = Luminance(material.emission) * inverseTotalPower * hit->t * hit->t / -cosAtHit;
  }
  const Rgb albedo =
      material.albedoTexture < 0 ? material.albedo : scene.AlbedoAt(hit->triangle, hit->b1, hit->b2);
  if (MaxComponent(albedo) <= 0.0f) return out;
  PathVertex v;
  v.geometricNormal = cosAtHit < 0.0f ? hitNormal : -hitNormal;
  v.frame = Frame::FromNormal(v.geometricNormal);
  const Vec3 hitPoint = origin + hit->t * direction;
  v.offset = OffsetAt(hitPoint);
  v.origin = hitPoint + v.offset * v.geometricNormal;
  // The hit is the end of the sample's first segment (with maxBounces 0,
  // direct light only, it reflects nothing).
  out.skyAndReflected = albedo * kInvPi * TracePath(at, v, rng, counters, /*firstSegment=*/1);
  return out;
}

namespace {

// Whether origin + t*direction, t > 0, meets the box (slab test).
bool RayMeetsBox(const Vec3& origin, const Vec3& direction, const Bounds3& box) {
  float tNear = 0.0f, tFar = kInfinity;
  for (int axis = 0; axis < 3; ++axis) {
    const float inverse = 1.0f / direction[axis];  // +-inf for 0: the slab test still holds
    float t0 = (box.min[axis] - origin[axis]) * inverse, t1 = (box.max[axis] - origin[axis]) * inverse;
    if (t0 > t1) std::swap(t0, t1);
    if (std::isnan(t0) || std::isnan(t1)) {  // parallel to the slab and on its boundary plane
      if (origin[axis] < box.min[axis] || origin[axis] > box.max[axis]) return false;
      continue;
    }
    tNear = std::max(tNear, t0);
    tFar = std::min(tFar, t1);
    if (tNear > tFar) return false;
  }
  return true;
}

// The directions from a point through a box: its silhouette -- the faces the
// point sees, as spherical triangles -- sampled uniformly in solid angle; or,
// from inside the box, the point's whole hemisphere.
class BoxSilhouette {
 public:
  BoxSilhouette(const Bounds3& box, const Vec3& point, const Frame& frame) : box_(box), frame_(frame) {
    const glm::dvec3 p(point);
    inside_ = true;
    for (int axis = 0; axis < 3; ++axis) inside_ = inside_ && point[axis] >= box.min[axis] && point[axis] <= box.max[axis];
    if (inside_) {
      solidAngle_ = 2.0 * double(kPi);
      return;
    }
    for (int axis = 0; axis < 3; ++axis) {
      const int u = (axis + 1) % 3, v = (axis + 2) % 3;
      for (int side = 0; side < 2; ++side) {
        // A face is seen from outside its plane; a flat box's one face once.
        const float plane = side == 0 ? box.min[axis] : box.max[axis];
        if (side == 0 ? !(point[axis] < plane) : !(point[axis] > plane)) continue;
        std::array<glm::dvec3, 4> corner;
        for (int k = 0; k < 4; ++k) {
          corner[k][axis] = plane;
          corner[k][u] = (k == 1 || k == 2) ? box.max[u] : box.min[u];
          corner[k][v] = (k >= 2) ? box.max[v] : box.min[v];
        }
        for (const auto& [i, j, k] : {std::array<int, 3>{0, 1, 2}, std::array<int, 3>{0, 2, 3}}) {
          Triangle& t = triangles_[count_++];
          t.corners = {corner[i], corner[j], corner[k]};
          for (int c = 0; c < 3; ++c) t.directions[c] = glm::normalize(t.corners[c] - p);
          t.solidAngle = sampling::SphericalTriangleArea(t.directions[0], t.directions[1], t.directions[2]);
          if (!std::isfinite(t.solidAngle)) t.solidAngle = 0.0;
          solidAngle_ += t.solidAngle;
        }
      }
    }
  }

  double SolidAngle() const { return solidAngle_; }

  // A direction of the silhouette (the hemisphere from inside), uniform in
  // solid angle: density 1 / SolidAngle() (triangles under ~1e-7 sr are
  // sampled by area on their plane, where the two agree).
  Vec3 Sample(const Vec3& point, float u0, float u1, float u2) const {
    if (inside_) {
      const float z = u1, r = std::sqrt(std::max(0.0f, 1.0f - z * z)), phi = 2.0f * kPi * u2;
      return frame_.ToWorld(Vec3(r * std::cos(phi), r * std::sin(phi), z));
    }
    double pick = double(u0) * solidAngle_;
    size_t chosen = 0;
    while (chosen + 1 < count_ && pick >= triangles_[chosen].solidAngle) pick -= triangles_[chosen++].solidAngle;
    const Triangle& t = triangles_[chosen];
    if (t.solidAngle < 1e-7) {
      const Vec2 b = sampling::UniformTriangle(u1, u2);
      const glm::dvec3 q = (1.0 - b.x - b.y) * t.corners[0] + double(b.x) * t.corners[1] + double(b.y) * t.corners[2];
      return Vec3(glm::normalize(q - glm::dvec3(point)));
    }
    return Vec3(sampling::SphericalTriangle(t.directions[0], t.directions[1], t.directions[2], t.solidAngle, u1, u2));
  }

  // Whether Sample() can return `direction`.
  bool Contains(const Vec3& origin, const Vec3& direction) const {
    return inside_ ? glm::dot(direction, frame_.n) > 0.0f : RayMeetsBox(origin, direction, box_);
  }

 private:
  struct Triangle {
    std::array<glm::dvec3, 3> corners;     // world space
    std::array<glm::dvec3, 3> directions;  // unit, from the point
    double solidAngle = 0.0;
  };
  Bounds3 box_;
  Frame frame_;
  bool inside_ = false;
  std::array<Triangle, 6> triangles_{};  // at most three faces seen, two triangles each
  size_t count_ = 0;
  double solidAngle_ = 0.0;
};

}  // namespace

ChangeEstimate Shader::EstimateChangeThrough(const PosedRayScene& before, const PosedRayScene& after,
                                             const ShadeInput& in, std::span<const Bounds3> region, int paths,
                                             ShadeCounters* counters, const std::atomic<bool>* cancel) const {
  const Impl& s = *impl_;
  ChangeEstimate out;
  if (paths <= 0 || region.empty()) return out;
  Pcg32 rng = Pcg32::ForSample(s.settings.seed, in.sampleId);
  ShadeCounters work;
  bool frontSide = true;
  const PathVertex start = s.SampleStart(before, in, rng, work, &frontSide);

  std::vector<BoxSilhouette> silhouettes;
  double totalSolidAngle = 0.0;
  for (const Bounds3& box : region) {
    if (box.Empty()) continue;
    BoxSilhouette silhouette(box, start.origin, start.frame);
    if (!(silhouette.SolidAngle() > 0.0)) continue;  // too far to subtend anything
    totalSolidAngle += silhouette.SolidAngle();
    silhouettes.push_back(std::move(silhouette));
  }
  if (silhouettes.empty()) return out;
  out.regionSolidAngle = float(totalSolidAngle);

  double sum = 0.0, sumSquares = 0.0;
  // Stratified numbers for what every paired sample draws first -- the
  // light, the point on it, the sun's direction, the silhouette and the
  // direction in it --, so that no part of a light or a silhouette goes
  // unsampled by chance (a penumbra's changed sliver of the light is what
  // independent samples miss). The spread of stratified samples overstates
  // their standard error: on the safe side for a test.
  const std::vector<float> lightChoice = sampling::Stratified1D(paths, rng);
  const std::vector<Vec2> onLight = sampling::Stratified2D(paths, rng);
  const std::vector<Vec2> inSunCone = sampling::Stratified2D(paths, rng);
  const std::vector<float> silhouetteChoice = sampling::Stratified1D(paths, rng);
  const std::vector<Vec2> inSilhouette = sampling::Stratified2D(paths, rng);
  for (int i = 0; i < paths; ++i) {
    // As in Shade: a shutdown need not wait for thousands of paths; the
    // caller drops the result.
    if (cancel && i % 32 == 31 && cancel->load(std::memory_order_relaxed)) break;
    const size_t k = size_t(i);
    double d = 0.0;
    // The area lights: a point on them, its shadow ray traced at both
    // poses. Only a ray toward a box can change (the rest are identical and
    // skipped); those the silhouette sampling below also finds, combined by
    // the balance heuristic -- light sampling finds a small light behind
    // the object, silhouette sampling a thin sliver of a large one that a
    // penumbra moves across.
    if (!s.lights.empty()) {
      const std::array<float, 4> u{lightChoice[k], rng.NextFloat(), onLight[k].x, onLight[k].y};
      const Impl::LightPoint light = s.SampleLightPoint(start, u);
      int containing = 0;
      if (light.pdf > 0.0f)
        for (const BoxSilhouette& silhouette : silhouettes) containing += silhouette.Contains(start.origin, light.direction);
      if (containing > 0) {
        const double silhouettePdf = double(containing) / totalSolidAngle;
        work.rays += 2;
        work.shadowRays += 2;
        const float reach = light.distance - start.offset;
        const bool litBefore = !before.Occluded(start.origin, light.direction, 0.0f, reach);
        const bool litAfter = !after.Occluded(start.origin, light.direction, 0.0f, reach);
        if (litBefore != litAfter) {
          const double weight = double(light.pdf) / (double(light.pdf) + silhouettePdf);
          d += (litAfter ? 1.0 : -1.0) * weight * double(Luminance(light.emission)) * double(light.cosAtVertex) /
               double(light.pdf);
        }
      }
    }
    if (s.scene.sun)
      d += double(Luminance(s.SampleSun(after, start, inSunCone[k], work)) -
                  Luminance(s.SampleSun(before, start, inSunCone[k], work)));

    // One box in proportion to its silhouette's solid angle, a direction
    // uniform in that; where silhouettes overlap the densities add up (a
    // one-sample mixture). What is left of the choosing number, rescaled,
    // chooses the silhouette's triangle.
    double pick = double(silhouetteChoice[k]) * totalSolidAngle;
    size_t chosen = 0;
    while (chosen + 1 < silhouettes.size() && pick >= silhouettes[chosen].SolidAngle())
      pick -= silhouettes[chosen++].SolidAngle();
    const float within = float(std::clamp(pick / silhouettes[chosen].SolidAngle(), 0.0, double(0x1.fffffep-1f)));
    const Vec3 direction = silhouettes[chosen].Sample(start.origin, within, inSilhouette[k].x, inSilhouette[k].y);
    // The path's continuation gets a stream of its own, copied for the
    // second pose: common random numbers.
    const uint64_t pathSeed = (uint64_t(rng.NextU32()) << 32) | rng.NextU32();
    const float cosTheta = glm::dot(direction, start.frame.n);
    if (cosTheta <= 0.0f || glm::dot(direction, start.geometricNormal) <= 0.0f) {  // no light from there
      sum += d;
      sumSquares += d * d;
      continue;
    }
    int containing = 0;
    for (const BoxSilhouette& silhouette : silhouettes) containing += silhouette.Contains(start.origin, direction);
    out.pathsThroughRegion += containing > 0;
    const double pdf = double(std::max(containing, 1)) / totalSolidAngle;
    Pcg32 atBefore(pathSeed, in.sampleId), atAfter = atBefore;
    // A light seen along the direction counts with the balance heuristic's
    // weight against the light sample above.
    const auto radiance = [&](const Impl::Incident& incident) {
      const double weight = incident.lightPdf > 0.0f ? pdf / (pdf + double(incident.lightPdf)) : 1.0;
      return weight * double(Luminance(incident.emitted)) + double(Luminance(incident.skyAndReflected));
    };
    const double lBefore = radiance(s.IncidentRadiance(before, start.origin, direction, atBefore, work));
    const double lAfter = radiance(s.IncidentRadiance(after, start.origin, direction, atAfter, work));
    d += (lAfter - lBefore) * double(cosTheta) / pdf;
    sum += d;
    sumSquares += d * d;
  }
  const double n = double(paths);
  const double mean = sum / n;
  out.irradianceChange = float(mean);
  out.standardError =
      paths > 1 ? float(std::sqrt(std::max(0.0, (sumSquares / n - mean * mean) * n / (n - 1.0)) / n)) : 0.0f;
  out.paths = uint32_t(paths);
  work.paths += 2 * uint64_t(paths);
  if (counters) *counters += work;
  return out;
}

// --- Shader -----------------------------------------------------------------

Shader::Shader(const Scene& scene, const RayScene& rays, ShadingSettings settings)
    : impl_(std::make_unique<const Impl>(scene, rays, settings)) {}
Shader::~Shader() = default;
Shader::Shader(Shader&&) noexcept = default;

const ShadingSettings& Shader::Settings() const { return impl_->settings; }
const Scene& Shader::GetScene() const { return impl_->scene; }
const RayScene& Shader::GetRays() const { return impl_->rays; }

ShadeOutput Shader::Shade(const ShadeInput& in, int paths, ShadeCounters* counters,
                          const std::atomic<bool>* cancel) const {
  return Shade(*impl_->rays.Initial(), in, paths, counters, cancel);
}

ShadeOutput Shader::Shade(const PosedRayScene& posed, const ShadeInput& in, int paths, ShadeCounters* counters,
                          const std::atomic<bool>* cancel) const {
  const Impl& s = *impl_;
  const PosedRayScene& at = posed;
  const int pathCount = paths > 0 ? paths : s.settings.pathsPerSample;
  Pcg32 rng = Pcg32::ForSample(s.settings.seed, in.sampleId);
  ShadeCounters work;
  bool frontSide = true;
  const PathVertex start = s.SampleStart(at, in, rng, work, &frontSide);
  Rgb sum(0.0f);
  int traced = 0;
  // Variance of the sum of the paths' luminances, block by block.
  double sumVariance = 0.0;
  // The luminance of E's standard error after `traced` paths (0 for one path).
  const auto standardError = [&] { return traced < 2 ? 0.0 : std::sqrt(sumVariance) / traced; };
  const int round = std::max(pathCount, 16);
  const int maxPaths = std::max(pathCount, s.settings.maxPathsPerSample);
  bool abandoned = false;
  std::vector<double> blockLuminance;
  for (int target = pathCount; traced < target;) {
    // The block's paths leave in stratified directions and take stratified
    // light and sun samples at the sample itself: where a surface sees a
    // bright patch or a window through a small part of its hemisphere, or
    // part of a light, the number of paths that find it no longer varies by
    // chance, only where in its cells they land. Each block (the asked
    // paths, then every adaptive round) is stratified on its own and its
    // variance estimated from neighbouring cells (JitteredSumVariance);
    // blocks are independent. Path k takes cell k of each grid -- the
    // direction, the sun's cone, the point on the light --, so that its
    // neighbours in the grid are its neighbours in all three and the
    // variance estimate sees each one's stratification. That is unbiased
    // because the three enter the path's estimate as separate terms (the
    // sun's, the light's, and what the direction finds), each a function of
    // its own numbers alone, each uniform; the light is chosen with numbers
    // of their own (a separate stratification, shuffled), independent of
    // the point on it.
    const int block = target - traced;
    int cells = 0;
    const std::vector<Vec2> directions = sampling::JitteredGrid(block, rng, &cells);
    const std::vector<Vec2> inSunCone = sampling::JitteredGrid(block, rng, &cells);
    const std::vector<Vec2> onLight = sampling::JitteredGrid(block, rng, &cells);
    const std::vector<float> lightChoice = sampling::Stratified1D(block, rng);
    blockLuminance.clear();
    for (size_t k = 0; traced < target; ++traced, ++k) {
      // Every 32 paths: cheap, and a shutdown need not wait for a sample of
      // thousands of paths. The caller drops an abandoned result.
      if (cancel && traced % 32 == 31 && cancel->load(std::memory_order_relaxed)) {
        abandoned = true;
        break;
      }
      const Impl::FirstVertexNumbers first{directions[k], inSunCone[k], lightChoice[k], onLight[k]};
      const Rgb estimate = s.TracePath(at, start, rng, work, 0, &first);
      sum += estimate;
      blockLuminance.push_back(Luminance(estimate));
    }
    if (abandoned) break;
    sumVariance += sampling::JitteredSumVariance(blockLuminance, cells);
    // Adaptive sampling: another round while the estimate is too uncertain.
    // Paths that all found nothing do not show that there is nothing to
    // find (a dim corner lit through one narrow gap reads 0 in most sets of
    // 16 paths): a black estimate is not known to be accurate.
    const double mean = Luminance(sum) / traced;
    if (traced < maxPaths && (mean == 0.0 || standardError() > double(s.settings.targetRelativeError) * mean))
      target = std::min(maxPaths, traced + round);
  }
  work.paths = uint64_t(traced);
  if (counters) *counters += work;

  ShadeOutput out;
  out.irradiance = sum / float(traced);
  out.irradianceStdErr = float(standardError());
  out.paths = uint32_t(traced);
  const Rgb emitted = frontSide ? s.scene.MaterialOf(in.triangle).emission : Rgb(0.0f);
  out.radiance = emitted + s.scene.AlbedoAt(in.triangle, in.b1, in.b2) * kInvPi * out.irradiance;
  return out;
}

}  // namespace penumbra
