#pragma once
// Shading of one surface sample by path tracing (Lambertian surfaces).
//
// Given a point x on base triangle `triangle`, with normal n, the shader
// estimates the irradiance
//     E(x) = integral over the hemisphere of n of L_in(x, w) cos(theta) dw
// and the radiance leaving x toward the n side,
//     L_out(x) = L_e(x) + albedo(x) / pi * E(x),
// where L_e is the emission of the triangle's material if n faces the same
// way as its front face (emitters emit from their front face only) and
// albedo(x) is the material's Kd times its texture at x.
//
// Incoming radiance comes from:
//  * area lights (emissive triangles): next-event estimation, picking a light
//    triangle in proportion to its power and a point uniformly on it, combined
//    with cosine-sampled directions by multiple importance sampling (power
//    heuristic);
//  * the sun: a disc of angular diameter d, sampled uniformly over its cone
//    (so its shadows have penumbrae); never reached by cosine sampling;
//  * the sky: radiance of escaping cosine-sampled directions;
//  * every other surface: diffuse interreflection, path length bounded by
//    max depth, with Russian roulette from `russianRouletteDepth` on.
// Every surface reflects on both sides with its material's albedo.
//
// Determinism: sample `sampleId` uses its own random stream, derived from
// (settings.seed, sampleId) only, so the same input gives the same output on
// any thread, in any batch, on any renderer process.

#include <cstdint>
#include <vector>

#include "penumbra/common/expected.h"
#include "penumbra/common/math.h"
#include "penumbra/common/scene.h"

namespace penumbra {

class RayScene;

struct ShadingSettings {
  int pathsPerSample = 64;       // --spp: paths averaged per sample
  int maxDepth = 5;              // --max-depth: path segments from the sample; 1 = direct light only
  int russianRouletteDepth = 3;  // first segment index at which paths may be terminated
  uint64_t seed = 0;             // global seed mixed into every sample's stream
};

struct ShadeInput {
  uint64_t sampleId = 0;
  Vec3 position;          // world space, on `triangle`
  Vec3 normal;            // world space, unit: the side of the surface to shade
  uint32_t triangle = 0;  // base triangle (Scene::triangles)
  float b1 = 0.0f;        // barycentrics of `position` on `triangle`
  float b2 = 0.0f;
};

struct ShadeOutput {
  Rgb radiance{0.0f};    // L_out: emitted + reflected, linear RGB
  Rgb irradiance{0.0f};  // E, linear RGB
};

/// Work done, for statistics and benchmarks.
struct ShadeCounters {
  uint64_t paths = 0;
  uint64_t rays = 0;  // closest-hit and shadow rays together
};

/// Checks one input against the scene: finite fields, unit normal (within
/// 1e-2), triangle in range, barycentrics in the triangle (within 1e-3), and
/// the position within a small distance of the triangle's point at those
/// barycentrics. The message names the field and its value.
Status ValidateShadeInput(const Scene& scene, const ShadeInput& input);

class Shader {
 public:
  /// `scene` and `rays` must outlive the shader.
  Shader(const Scene& scene, const RayScene& rays, ShadingSettings settings);

  /// Shades one sample with `paths` paths (the settings' count when 0).
  /// Input must have passed ValidateShadeInput. Thread-safe; deterministic.
  ShadeOutput Shade(const ShadeInput& input, int paths, ShadeCounters* counters) const;

  const ShadingSettings& Settings() const { return settings_; }
  const Scene& GetScene() const { return scene_; }

 private:
  const Scene& scene_;
  const RayScene& rays_;
  ShadingSettings settings_;
  // Light selection: cumulative power of emissive triangles.
  std::vector<float> lightCdf_;
  float totalLightPower_ = 0.0f;
};

}  // namespace penumbra
