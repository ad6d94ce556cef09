#pragma once
// Warps from the unit square to the distributions the shader samples, with
// their densities; the MIS weight that combines two of them; and an alias
// table for picking among weighted items. Directions are in a local frame
// with the axis of interest as +z.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <span>
#include <vector>

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

/// Walker's alias method (Vose's construction): draws index i with
/// probability weights[i] / sum(weights) in constant time, however many
/// entries there are.
class AliasTable {
 public:
  AliasTable() = default;
  /// `weights` are non-negative with a positive sum.
  explicit AliasTable(std::span<const double> weights) : bins_(weights.size()) {
    double sum = 0.0;
    for (double w : weights) sum += w;
    // Scaled so that the mean bin holds exactly 1; split into bins below and
    // at-or-above the mean, then let each small bin borrow from a large one.
    std::vector<double> scaled(weights.size());
    std::vector<uint32_t> small, large;
    for (size_t i = 0; i < weights.size(); ++i) {
      scaled[i] = weights[i] / sum * double(weights.size());
      (scaled[i] < 1.0 ? small : large).push_back(uint32_t(i));
    }
    while (!small.empty() && !large.empty()) {
      const uint32_t s = small.back(), l = large.back();
      small.pop_back();
      bins_[s] = Bin{float(scaled[s]), l};
      scaled[l] -= 1.0 - scaled[s];
      if (scaled[l] < 1.0) {
        large.pop_back();
        small.push_back(l);
      }
    }
    // What remains holds 1 up to rounding.
    for (uint32_t i : large) bins_[i] = Bin{1.0f, i};
    for (uint32_t i : small) bins_[i] = Bin{1.0f, i};
  }

  size_t size() const { return bins_.size(); }

  /// An index from two uniforms in [0, 1).
  uint32_t Sample(float u1, float u2) const {
    const uint32_t i = std::min(uint32_t(u1 * float(bins_.size())), uint32_t(bins_.size() - 1));
    return u2 < bins_[i].probability ? i : bins_[i].alias;
  }

 private:
  struct Bin {
    float probability = 1.0f;  // of keeping this bin's own index
    uint32_t alias = 0;        // taken otherwise
  };
  std::vector<Bin> bins_;
};

}  // namespace penumbra::sampling
