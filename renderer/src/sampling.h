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

/// Solid angle of the spherical triangle with unit vertices a, b, c (Van
/// Oosterom & Strackee 1983): stable for small triangles, where the angle
/// excess alpha + beta + gamma - pi cancels catastrophically.
inline double SphericalTriangleArea(const glm::dvec3& a, const glm::dvec3& b, const glm::dvec3& c) {
  return 2.0 * std::atan2(std::abs(glm::dot(a, glm::cross(b, c))),
                          1.0 + glm::dot(a, b) + glm::dot(b, c) + glm::dot(c, a));
}

/// Direction uniform in solid angle over the spherical triangle with unit
/// vertices a, b, c and solid angle `area` (SphericalTriangleArea), so with
/// density 1 / area (Arvo 1995, "Stratified sampling of spherical
/// triangles"): u1 picks the sub-triangle a-b-c' of area u1 * area, u2 the
/// point on the arc from b to c'. Doubles: the construction loses digits for
/// small triangles. Callers sample a triangle too small for that (below
/// ~1e-7 sr) uniformly by area on its plane instead, where the two agree.
inline glm::dvec3 SphericalTriangle(const glm::dvec3& a, const glm::dvec3& b, const glm::dvec3& c, double area,
                                    double u1, double u2) {
  // The unit tangent at `at` of the great arc toward p.
  const auto tangent = [](const glm::dvec3& at, const glm::dvec3& p) {
    const glm::dvec3 t = p - glm::dot(at, p) * at;
    const double length = glm::length(t);
    return length > 0.0 ? t / length : glm::dvec3(0.0);
  };
  const double cosAlpha = std::clamp(glm::dot(tangent(a, b), tangent(a, c)), -1.0, 1.0);
  const double sinAlpha = std::sqrt(std::max(0.0, 1.0 - cosAlpha * cosAlpha));
  const double alpha = std::acos(cosAlpha);
  const double areaHat = u1 * area;
  const double s = std::sin(areaHat - alpha), t = std::cos(areaHat - alpha);
  const double u = t - cosAlpha;
  const double v = s + sinAlpha * glm::dot(a, b);
  const double denominator = (v * s + u * t) * sinAlpha;
  const double q = denominator != 0.0 ? std::clamp(((v * t - u * s) * cosAlpha - v) / denominator, -1.0, 1.0) : 1.0;
  const glm::dvec3 cHat = q * a + std::sqrt(std::max(0.0, 1.0 - q * q)) * tangent(a, c);
  const double z = std::clamp(1.0 - u2 * (1.0 - glm::dot(cHat, b)), -1.0, 1.0);
  return z * b + std::sqrt(std::max(0.0, 1.0 - z * z)) * tangent(b, cHat);
}

/// `n` values in [0, 1), one uniform in each of the strata [i/n, (i+1)/n),
/// in random order: for an estimator that draws all its samples at once, so
/// that no stretch of the domain is left out by chance.
template <typename Rng>
std::vector<float> Stratified1D(int n, Rng& rng) {
  std::vector<float> values(size_t(std::max(n, 0)));
  for (size_t i = 0; i < values.size(); ++i)
    values[i] = std::min((float(i) + rng.NextFloat()) / float(n), 0x1.fffffep-1f);
  for (size_t i = values.size(); i > 1; --i) std::swap(values[i - 1], values[rng.NextBelow(uint32_t(i))]);
  return values;
}

/// `n` points of the unit square for an estimate whose variance is then
/// estimated from them (JitteredSumVariance): one uniform in each cell of the
/// largest g x g grid with g^2 <= n, in row-major cell order (cell i at
/// column i % g, row i / g), then n - g^2 uniform anywhere. `*cells` = g^2.
template <typename Rng>
std::vector<Vec2> JitteredGrid(int n, Rng& rng, int* cells) {
  std::vector<Vec2> points(size_t(std::max(n, 0)));
  const int g = int(std::sqrt(double(std::max(n, 0))));
  *cells = g * g;
  for (size_t i = 0; i < points.size(); ++i) {
    const float u = rng.NextFloat(), v = rng.NextFloat();
    points[i] = int(i) < g * g ? Vec2(std::min((float(int(i) % g) + u) / float(g), 0x1.fffffep-1f),
                                      std::min((float(int(i) / g) + v) / float(g), 0x1.fffffep-1f))
                               : Vec2(u, v);
  }
  return points;
}

/// `n` points of the unit square: one uniform in each cell of the largest
/// g x g grid with g^2 <= n, the rest uniform anywhere, in random order
/// (JitteredGrid's points, shuffled).
template <typename Rng>
std::vector<Vec2> Stratified2D(int n, Rng& rng) {
  int cells = 0;
  std::vector<Vec2> points = JitteredGrid(n, rng, &cells);
  for (size_t i = points.size(); i > 1; --i) std::swap(points[i - 1], points[rng.NextBelow(uint32_t(i))]);
  return points;
}

/// Variance of the sum of `values`, where values[i] is an estimate drawn at
/// JitteredGrid's point i and `cells` is its grid's size. The spread of
/// independent samples would overstate it many times over for a smooth
/// integrand: stratification removes what varies from cell to cell, and only
/// the variation within each cell is left. That is estimated along each row
/// of the grid from second differences of neighbouring cells,
/// f_i - 2 f_i+1 + f_i+2: their square's expectation is the three cells'
/// variances (1 + 4 + 1 of them) plus the square of the integrand's
/// curvature across them -- a trend along the row cancels, and rows differ
/// freely --, so it errs on the safe side only where the integrand bends
/// from one cell to the next. Grids of two cells a side pair the cells
/// instead ((f_2j - f_2j+1)^2: the pair's variances plus the square of their
/// means' difference). The points outside the grid count as independent
/// samples, with the spread of all the values. 0 for fewer than two values.
inline double JitteredSumVariance(std::span<const double> values, int cells) {
  const size_t n = values.size();
  if (n < 2) return 0.0;
  const size_t side = size_t(std::sqrt(double(std::max(cells, 0)) + 0.5));
  const size_t inGrid = std::min(side * side, n);
  double variance = 0.0;
  size_t covered = 0;  // grid cells whose variance is estimated above
  if (side >= 3 && inGrid == side * side) {
    double squares = 0.0;
    size_t count = 0;
    for (size_t row = 0; row < side; ++row)
      for (size_t i = row * side; i + 2 < (row + 1) * side; ++i) {
        const double d = values[i] - 2.0 * values[i + 1] + values[i + 2];
        squares += d * d;
        ++count;
      }
    variance += double(inGrid) * squares / (6.0 * double(count));
    covered = inGrid;
  } else {
    covered = inGrid / 2 * 2;
    for (size_t i = 0; i < covered; i += 2) {
      const double d = values[i] - values[i + 1];
      variance += d * d;
    }
  }
  if (covered < n) {
    double mean = 0.0;
    for (double v : values) mean += v;
    mean /= double(n);
    double squares = 0.0;
    for (double v : values) squares += (v - mean) * (v - mean);
    variance += double(n - covered) * squares / double(n - 1);
  }
  return variance;
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
