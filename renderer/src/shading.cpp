// Path tracer for vertex samples; the contract is in shading.h.
//
// Estimator. `throughput` is the factor that turns an estimate of the
// cosine-weighted incident integral at the current path vertex into its
// contribution to E at the sample. It starts at 1 (E itself has no albedo);
// a cosine-sampled bounce contributes L_in * pi (cos / pdf), and the next
// vertex's integral enters through albedo / pi, so each bounce multiplies the
// throughput by the albedo it meets.

#include "penumbra/renderer/shading.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>

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

float MaxComponent(const Rgb& c) { return std::max({c.r, c.g, c.b}); }

float LargestCoordinate(const Bounds3& b) {
  const Vec3 m = glm::max(glm::abs(b.min), glm::abs(b.max));
  return std::max({m.x, m.y, m.z});
}

}  // namespace

/// A point paths leave from: the ray origin (already off the surface), the
/// frame of the normal that weights incident light (z), and the geometric
/// normal of its triangle on the same side (below which nothing arrives).
struct Shader::PathVertex {
  Vec3 origin;
  Frame frame;
  Vec3 geometricNormal;
};

// --- Validation -------------------------------------------------------------

Status ValidateShadeInput(const Scene& scene, const ShadeInput& in) {
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
  const float tolerance = 1e-4f * glm::length(scene.bounds.Diagonal());
  const float distance = glm::length(in.position - scene.PointAt(in.triangle, in.b1, in.b2));
  if (!(distance <= tolerance))
    return Fail(fmt::format("position ({}, {}, {}) is {} away from triangle {} at barycentrics ({}, {}) "
                            "(tolerance {})",
                            in.position.x, in.position.y, in.position.z, distance, in.triangle, in.b1, in.b2,
                            tolerance));
  return Status::Ok();
}

// --- Shader -----------------------------------------------------------------

Shader::Shader(const Scene& scene, const RayScene& rays, ShadingSettings settings)
    : scene_(scene), rays_(rays), settings_(settings), triangles_(scene.triangles.size()) {
  for (uint32_t t = 0; t < scene.triangles.size(); ++t) triangles_[t].normal = scene.GeometricNormal(t);

  // Power of an emitter is proportional to its emitted radiance times its
  // area (the pi of a Lambertian emitter is common to all).
  std::vector<double> power;
  double totalPower = 0.0;
  for (uint32_t t : scene.emissiveTriangles) {
    const double p = double(Luminance(scene.MaterialOf(t).emission)) * double(scene.Area(t));
    if (!(p > 0.0)) continue;
    lights_.push_back(t);
    power.push_back(p);
    totalPower += p;
  }
  double cumulative = 0.0;
  for (size_t i = 0; i < lights_.size(); ++i) {
    triangles_[lights_[i]].lightPdfArea = float(power[i] / totalPower / double(scene.Area(lights_[i])));
    cumulative += power[i];
    lightCdf_.push_back(float(cumulative / totalPower));
  }
  if (!lightCdf_.empty()) lightCdf_.back() = 1.0f;

  if (scene.sun) {
    sunFrame_ = Frame::FromNormal(scene.sun->directionToSun);
    sunCosHalfAngle_ = scene.sun->CosHalfAngle();
    sunSolidAngle_ = scene.sun->SolidAngle();
  }
  offset_ = kRelativeOffset * LargestCoordinate(scene.bounds);
}

ShadeOutput Shader::Shade(const ShadeInput& in, int paths, ShadeCounters* counters) const {
  const int pathCount = paths > 0 ? paths : settings_.pathsPerSample;
  const Vec3 normal = glm::normalize(in.normal);
  const Vec3& faceNormal = triangles_[in.triangle].normal;
  const bool frontSide = glm::dot(normal, faceNormal) >= 0.0f;

  PathVertex start;
  start.frame = Frame::FromNormal(normal);
  start.geometricNormal = frontSide ? faceNormal : -faceNormal;
  // Off the surface along the normal, and into the triangle toward its
  // centroid (no further than halfway), so that a neighbour meeting this
  // vertex or edge at an angle -- a wall at the edge of a floor -- lies
  // clearly on one side of the origin.
  const Vec3 centroid = scene_.PointAt(in.triangle, 1.0f / 3.0f, 1.0f / 3.0f);
  const Vec3 toCentroid = centroid - in.position;
  const float toCentroidLength = glm::length(toCentroid);
  start.origin = in.position + offset_ * start.geometricNormal;
  if (toCentroidLength > 0.0f)
    start.origin += toCentroid * (std::min(offset_, 0.5f * toCentroidLength) / toCentroidLength);

  Pcg32 rng = Pcg32::ForSample(settings_.seed, in.sampleId);
  ShadeCounters work;
  Rgb sum(0.0f);
  for (int p = 0; p < pathCount; ++p) sum += TracePath(start, rng, work);
  work.paths = uint64_t(pathCount);
  if (counters) *counters += work;

  ShadeOutput out;
  out.irradiance = sum / float(pathCount);
  const Rgb emitted = frontSide ? scene_.MaterialOf(in.triangle).emission : Rgb(0.0f);
  out.radiance = emitted + scene_.AlbedoAt(in.triangle, in.b1, in.b2) * kInvPi * out.irradiance;
  return out;
}

Rgb Shader::TracePath(const PathVertex& start, Pcg32& rng, ShadeCounters& counters) const {
  PathVertex v = start;
  Rgb throughput(1.0f);
  Rgb irradiance(0.0f);
  for (int depth = 0; depth < settings_.maxDepth; ++depth) {
    if (!lights_.empty()) irradiance += throughput * SampleAreaLight(v, rng, counters);
    if (scene_.sun) irradiance += throughput * SampleSun(v, rng, counters);

    const Vec3 local = sampling::CosineHemisphere(rng.NextFloat(), rng.NextFloat());
    const Vec3 direction = v.frame.ToWorld(local);
    if (glm::dot(direction, v.geometricNormal) <= 0.0f) break;  // into the surface itself
    ++counters.rays;
    const std::optional<RayHit> hit = rays_.Intersect(v.origin, direction, 0.0f, kInfinity);
    // Cosine-weighted incident radiance over the cosine pdf: a factor pi.
    if (!hit) {
      if (scene_.sky) irradiance += throughput * kPi * scene_.sky->Radiance(direction);
      break;
    }
    const TriangleInfo& info = triangles_[hit->triangle];
    const float cosAtHit = glm::dot(info.normal, direction);  // < 0: the front face was hit
    const Material& material = scene_.MaterialOf(hit->triangle);
    if (cosAtHit < 0.0f && material.IsEmissive()) {
      // The light sample at `v` could have produced this point too.
      const float pdfLight = info.lightPdfArea * hit->t * hit->t / -cosAtHit;
      const float weight = sampling::PowerHeuristic(sampling::CosineHemispherePdf(local.z), pdfLight);
      irradiance += throughput * kPi * weight * material.emission;
    }
    if (depth + 1 == settings_.maxDepth) break;

    const Rgb albedo = scene_.AlbedoAt(hit->triangle, hit->b1, hit->b2);
    throughput *= albedo;
    if (depth + 1 >= settings_.russianRouletteDepth) {
      // Survival in proportion to the albedo: in a uniform scene the
      // throughput then stays constant instead of decaying.
      const float survival = std::min(1.0f, MaxComponent(albedo));
      if (rng.NextFloat() >= survival) break;
      throughput /= survival;
    }
    if (MaxComponent(throughput) <= 0.0f) break;

    // Both sides reflect: shade the side the path arrived from.
    v.geometricNormal = cosAtHit < 0.0f ? info.normal : -info.normal;
    v.frame = Frame::FromNormal(v.geometricNormal);
    v.origin = scene_.PointAt(hit->triangle, hit->b1, hit->b2) + offset_ * v.geometricNormal;
  }
  return irradiance;
}

Rgb Shader::SampleAreaLight(const PathVertex& v, Pcg32& rng, ShadeCounters& counters) const {
  const float u = rng.NextFloat();
  const size_t index = std::min(size_t(std::upper_bound(lightCdf_.begin(), lightCdf_.end(), u) - lightCdf_.begin()),
                                lights_.size() - 1);
  const uint32_t light = lights_[index];
  const Vec2 b = sampling::UniformTriangle(rng.NextFloat(), rng.NextFloat());
  const Vec3 onLight = scene_.PointAt(light, b.x, b.y);

  const Vec3 toLight = onLight - v.origin;
  const float distance2 = glm::dot(toLight, toLight);
  const float distance = std::sqrt(distance2);
  const Vec3 direction = toLight / distance;
  const float cosAtVertex = glm::dot(direction, v.frame.n);
  const TriangleInfo& info = triangles_[light];
  const float cosAtLight = -glm::dot(direction, info.normal);  // emitters emit from the front only
  if (cosAtVertex <= 0.0f || cosAtLight <= 0.0f || glm::dot(direction, v.geometricNormal) <= 0.0f)
    return Rgb(0.0f);

  ++counters.rays;
  ++counters.shadowRays;
  // Stop short of the light so that its own surface does not occlude it.
  if (rays_.Occluded(v.origin, direction, 0.0f, distance - offset_)) return Rgb(0.0f);
  const float pdfLight = info.lightPdfArea * distance2 / cosAtLight;
  const float weight = sampling::PowerHeuristic(pdfLight, sampling::CosineHemispherePdf(cosAtVertex));
  return scene_.MaterialOf(light).emission * (weight * cosAtVertex / pdfLight);
}

Rgb Shader::SampleSun(const PathVertex& v, Pcg32& rng, ShadeCounters& counters) const {
  const Vec3 direction =
      sunFrame_.ToWorld(sampling::UniformCone(rng.NextFloat(), rng.NextFloat(), sunCosHalfAngle_));
  const float cosAtVertex = glm::dot(direction, v.frame.n);
  if (cosAtVertex <= 0.0f || glm::dot(direction, v.geometricNormal) <= 0.0f) return Rgb(0.0f);
  ++counters.rays;
  ++counters.shadowRays;
  if (rays_.Occluded(v.origin, direction, 0.0f, kInfinity)) return Rgb(0.0f);
  // Uniform over the cone: radiance * cos / (1 / solid angle).
  return scene_.sun->radiance * (cosAtVertex * sunSolidAngle_);
}

}  // namespace penumbra
