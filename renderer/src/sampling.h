#pragma once
// Warps from the unit square to the distributions the shader samples, with
// their densities, and the MIS weight that combines two of them. Directions
// are in a local frame with the axis of interest as +z.

#include <cmath>

#include "penumbra/common/math.h"

namespace penumbra::sampling {

/// Direction on the +z hemisphere with density cos(theta) / pi (Malley:
/// uniform on the disc, lifted). Its z is cos(theta).
inline Vec3 CosineHemisphere(float u1, float u2) {
  const float r = std::sqrt(u1);
  const float phi = 2.0f * kPi * u2;
  return Vec3(r * std::cos(phi), r * std::sin(phi), std::sqrt(std::max(0.0f, 1.0f - u1)));
}

inline float CosineHemispherePdf(float cosTheta) { return cosTheta * kInvPi; }

/// Direction uniform in the cone of half-angle acos(cosMax) about +z, with
/// density 1 / (2 pi (1 - cosMax)).
inline Vec3 UniformCone(float u1, float u2, float cosMax) {
  const float cosTheta = 1.0f - u1 * (1.0f - cosMax);
  const float sinTheta = std::sqrt(std::max(0.0f, 1.0f - cosTheta * cosTheta));
  const float phi = 2.0f * kPi * u2;
  return Vec3(sinTheta * std::cos(phi), sinTheta * std::sin(phi), cosTheta);
}

/// Barycentrics (b1, b2) of a point uniform in area on a triangle.
inline Vec2 UniformTriangle(float u1, float u2) {
  const float s = std::sqrt(u1);
  return Vec2(u2 * s, s - u2 * s);
}

/// Veach's power heuristic (beta = 2): the weight of a sample drawn from
/// density `pdfChosen` (> 0) when `pdfOther` could also have drawn it.
inline float PowerHeuristic(float pdfChosen, float pdfOther) {
  const float a = pdfChosen * pdfChosen;
  const float b = pdfOther * pdfOther;
  return a / (a + b);
}

}  // namespace penumbra::sampling
