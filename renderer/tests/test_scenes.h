#pragma once
// Helpers for the renderer's tests: analytic scenes built in code, samples
// placed on them, and Monte Carlo estimates with their standard errors.

#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <optional>
#include <string>

#include "penumbra/common/scene.h"
#include "penumbra/renderer/ray_scene.h"
#include "penumbra/renderer/shading.h"

namespace penumbra::testing {

inline Material MakeMaterial(Rgb albedo, Rgb emission = Rgb(0.0f)) {
  Material m;
  m.albedo = albedo;
  m.emission = emission;
  return m;
}

/// One face of the axis-aligned box [lo, hi]: the one on `axis` (0..2) at
/// `side` (0: lo, 1: hi), its front facing into the box (`inward`) or out.
inline void AddBoxFace(SceneBuilder& b, const Vec3& lo, const Vec3& hi, int axis, int side, uint32_t material,
                       bool inward) {
  const Vec3 size = hi - lo;
  Vec3 front(0.0f);
  front[axis] = (side == 0) == inward ? 1.0f : -1.0f;
  Vec3 corner = lo;
  corner[axis] = side == 0 ? lo[axis] : hi[axis];
  Vec3 e1(0.0f), e2(0.0f);
  e1[(axis + 1) % 3] = size[(axis + 1) % 3];
  e2[(axis + 2) % 3] = size[(axis + 2) % 3];
  if (glm::dot(glm::cross(e1, e2), front) < 0.0f) std::swap(e1, e2);
  b.AddQuad(corner, e1, e2, material);
}

/// An axis-aligned box of six quads with their fronts facing inward (a room)
/// or outward (a block). `materials` per face: -x, +x, -y, +y, -z, +z.
inline void AddBox(SceneBuilder& b, const Vec3& lo, const Vec3& hi, const std::array<uint32_t, 6>& materials,
                   bool inward) {
  for (int axis = 0; axis < 3; ++axis)
    for (int side = 0; side < 2; ++side) AddBoxFace(b, lo, hi, axis, side, materials[size_t(2 * axis + side)], inward);
}

inline void AddBox(SceneBuilder& b, const Vec3& lo, const Vec3& hi, uint32_t material, bool inward) {
  AddBox(b, lo, hi, {material, material, material, material, material, material}, inward);
}

/// A horizontal square of side `side` centred at `centre`, front facing up
/// (+y) or down.
inline void AddHorizontalSquare(SceneBuilder& b, const Vec3& centre, float side, uint32_t material,
                                bool facingUp) {
  const Vec3 corner = centre - Vec3(0.5f * side, 0.0f, 0.5f * side);
  const Vec3 ex(side, 0.0f, 0.0f), ez(0.0f, 0.0f, side);
  if (facingUp)
    b.AddQuad(corner, ez, ex, material);  // cross(z, x) = +y
  else
    b.AddQuad(corner, ex, ez, material);
}

inline constexpr Vec3 kUp(0.0f, 1.0f, 0.0f);

/// Shading with no bounce: emission and direct light only.
inline ShadingSettings DirectOnly() {
  ShadingSettings s;
  s.maxBounces = 0;
  return s;
}

/// A built scene with its ray scene, kept together for a test's lifetime.
struct TestScene {
  Scene scene;
  std::unique_ptr<RayScene> rays;
};

inline TestScene Finish(SceneBuilder& b, Scene scene = {}) {
  TestScene t;
  t.scene = std::move(scene);
  if (t.scene.name.empty()) t.scene.name = "test";
  const Status built = b.BuildInto(t.scene);
  EXPECT_TRUE(built.ok()) << (built.ok() ? "" : built.error().message);
  auto rays = RayScene::Build(t.scene);
  EXPECT_TRUE(rays.ok()) << (rays.ok() ? "" : rays.error().message);
  if (rays.ok()) t.rays = std::move(*rays);
  return t;
}

/// A sample at `position` on a triangle of `scene` that contains it and lies
/// in a plane normal to `normal` (either side), shading the `normal` side.
inline ShadeInput SampleAt(const Scene& scene, const Vec3& position, const Vec3& normal, uint64_t sampleId = 0) {
  for (uint32_t t = 0; t < scene.triangles.size(); ++t) {
    const Vec3 n = scene.GeometricNormal(t);
    if (std::abs(glm::dot(n, normal)) < 0.999f) continue;
    const Vec3 p0 = scene.Position(t, 0);
    const Vec3 e1 = scene.Position(t, 1) - p0, e2 = scene.Position(t, 2) - p0, d = position - p0;
    if (std::abs(glm::dot(d, n)) > 1e-5f) continue;
    // Barycentrics by Cramer's rule in the triangle's plane.
    const float d11 = glm::dot(e1, e1), d12 = glm::dot(e1, e2), d22 = glm::dot(e2, e2);
    const float d1 = glm::dot(d, e1), d2 = glm::dot(d, e2);
    const float det = d11 * d22 - d12 * d12;
    const float b1 = (d22 * d1 - d12 * d2) / det, b2 = (d11 * d2 - d12 * d1) / det;
    if (b1 < -1e-6f || b2 < -1e-6f || b1 + b2 > 1.0f + 1e-6f) continue;
    ShadeInput in;
    in.sampleId = sampleId;
    in.position = position;
    in.normal = normal;
    in.triangle = t;
    in.b1 = b1;
    in.b2 = b2;
    return in;
  }
  ADD_FAILURE() << "no triangle contains (" << position.x << ", " << position.y << ", " << position.z << ")";
  return {};
}

/// Irradiance at a point from a parallel, downward-facing Lambertian
/// rectangle of radiance `radiance` at height h spanning [x0, x1] x [z0, z1]
/// relative to the point's foot. The corner term is the classic form factor
/// of a rectangle with one corner above the point, times 2 pi; it is odd in
/// both arguments, so any rectangle is a signed sum of four corners.
inline double ParallelRectangleIrradiance(double radiance, double h, double x0, double x1, double z0, double z1) {
  auto corner = [h](double x, double z) {
    const double a = x / h, b = z / h;
    const double sa = std::sqrt(1.0 + a * a), sb = std::sqrt(1.0 + b * b);
    return a / sa * std::atan(b / sa) + b / sb * std::atan(a / sb);
  };
  return 0.5 * radiance * (corner(x1, z1) - corner(x0, z1) - corner(x1, z0) + corner(x0, z0));
}

/// A Monte Carlo estimate and its standard error, per channel.
struct Estimate {
  Rgb mean{0.0f};
  Rgb standardError{0.0f};
};

/// Shades `input` under `batches` different sample ids with `paths` paths
/// each. The spread of the batch results gives the standard error of their
/// mean without knowing the estimator's variance in advance.
inline Estimate EstimateOutput(const Shader& shader, ShadeInput input, int batches, int paths,
                               Rgb ShadeOutput::*field) {
  Rgb sum(0.0f), sumSquares(0.0f);
  for (int i = 0; i < batches; ++i) {
    input.sampleId = 1000 + uint64_t(i);
    const Rgb value = shader.Shade(input, paths, nullptr).*field;
    sum += value;
    sumSquares += value * value;
  }
  const float n = float(batches);
  Estimate e;
  e.mean = sum / n;
  const Rgb variance = glm::max(Rgb(0.0f), (sumSquares - n * e.mean * e.mean) / (n - 1.0f));
  e.standardError = glm::sqrt(variance / n);
  return e;
}

/// Whether an estimate agrees with the exact value: within `sigmas` standard
/// errors, plus float rounding (some estimators here have no variance at
/// all). Also requires the estimate to be precise to `maxRelativeError`, so
/// that a noisy estimate cannot pass by being vague.
inline ::testing::AssertionResult Agrees(const Estimate& e, const Rgb& exact, float maxRelativeError,
                                         float sigmas = 5.0f) {
  for (int c = 0; c < 3; ++c) {
    const float rounding = 1e-5f * std::abs(exact[c]) + 1e-7f;
    const float tolerance = sigmas * e.standardError[c] + rounding;
    if (!(std::abs(e.mean[c] - exact[c]) <= tolerance))
      return ::testing::AssertionFailure() << "channel " << c << ": estimate " << e.mean[c] << " vs exact "
                                           << exact[c] << ", tolerance " << tolerance << " ("
                                           << e.standardError[c] << " standard error)";
    if (!(e.standardError[c] <= maxRelativeError * std::abs(exact[c]) + 1e-7f))
      return ::testing::AssertionFailure() << "channel " << c << ": standard error " << e.standardError[c]
                                           << " too large to test against " << exact[c];
  }
  return ::testing::AssertionSuccess();
}

}  // namespace penumbra::testing
