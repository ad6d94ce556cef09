// Moments of the sampling warps against their closed forms. Each check
// averages N samples and allows 5 standard deviations of that mean, from the
// known variance of the sampled quantity.

#include "sampling.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <numbers>
#include <vector>

#include "penumbra/common/rng.h"

namespace penumbra::sampling {
namespace {

constexpr int kN = 1 << 16;

TEST(SamplingTest, CosineHemisphereHasMeanCosineTwoThirds) {
  Pcg32 rng(1, 2);
  double sum = 0.0;
  for (int i = 0; i < kN; ++i) {
    const Vec3 w = CosineHemisphere(rng.NextFloat(), rng.NextFloat());
    ASSERT_NEAR(glm::length(w), 1.0f, 1e-5f);
    ASSERT_GT(w.z, 0.0f);
    sum += w.z;
  }
  // cos theta = sqrt(1 - u): mean 2/3, variance 1/2 - 4/9 = 1/18.
  EXPECT_NEAR(sum / kN, 2.0 / 3.0, 5.0 * std::sqrt(1.0 / 18.0 / kN));
}

TEST(SamplingTest, UniformConeStaysInsideAndIsUniformInCosine) {
  Pcg32 rng(3, 4);
  const float cosMax = std::cos(0.2f);
  double sum = 0.0;
  for (int i = 0; i < kN; ++i) {
    const Vec3 w = UniformCone(rng.NextFloat(), rng.NextFloat(), cosMax);
    ASSERT_NEAR(glm::length(w), 1.0f, 1e-5f);
    ASSERT_GE(w.z, cosMax - 1e-6f);
    sum += w.z;
  }
  // Uniform in solid angle is uniform in cos theta on [cosMax, 1].
  const double width = 1.0 - cosMax;
  EXPECT_NEAR(sum / kN, 1.0 - 0.5 * width, 5.0 * width / std::sqrt(12.0 * kN));
}

TEST(SamplingTest, UniformTriangleStaysInsideWithCentroidMean) {
  Pcg32 rng(5, 6);
  Vec2 sum(0.0f);
  for (int i = 0; i < kN; ++i) {
    const Vec2 b = UniformTriangle(rng.NextFloat(), rng.NextFloat());
    ASSERT_GE(b.x, 0.0f);
    ASSERT_GE(b.y, 0.0f);
    ASSERT_LE(b.x + b.y, 1.0f + 1e-6f);
    sum += b;
  }
  // Each barycentric is Beta(1, 2): mean 1/3, variance 1/18.
  const double tolerance = 5.0 * std::sqrt(1.0 / 18.0 / kN);
  EXPECT_NEAR(sum.x / kN, 1.0 / 3.0, tolerance);
  EXPECT_NEAR(sum.y / kN, 1.0 / 3.0, tolerance);
}

// Each index's frequency is binomial: within 5 standard deviations of N p.
// The octant triangle (x, y, z axes) has solid angle pi / 2, and the half
// of it above 60 degrees from each axis -- the cap x > 1/2 (or y, or z) --
// holds half its solid angle: uniform samples put half there, whichever
// vertex the construction treats first.
TEST(SamplingTest, SphericalTriangleIsUniformOverTheOctant) {
  const glm::dvec3 x(1, 0, 0), y(0, 1, 0), z(0, 0, 1);
  const double area = sampling::SphericalTriangleArea(x, y, z);
  EXPECT_NEAR(area, std::numbers::pi / 2.0, 1e-12);
  Pcg32 rng(3, 5);
  constexpr int kSamples = 200000;
  std::array<int, 3> nearAxis{};
  for (int i = 0; i < kSamples; ++i) {
    const glm::dvec3 w = sampling::SphericalTriangle(x, y, z, area, rng.NextFloat(), rng.NextFloat());
    ASSERT_NEAR(glm::length(w), 1.0, 1e-9);
    ASSERT_GE(std::min({w.x, w.y, w.z}), -1e-9) << "outside the triangle";
    for (int axis = 0; axis < 3; ++axis) nearAxis[axis] += w[axis] > 0.5;
  }
  const double sigma = std::sqrt(0.25 / kSamples);
  for (int axis = 0; axis < 3; ++axis) EXPECT_NEAR(double(nearAxis[axis]) / kSamples, 0.5, 4.0 * sigma) << axis;
}

// A small, thin, oblique triangle: its solid angle agrees with the planar
// estimate (area * cos / d^2), and its samples' mean direction with the
// direction to its centroid.
TEST(SamplingTest, SphericalTriangleHandlesSmallObliqueTriangles) {
  const glm::dvec3 p0(10.0, 0.0, 0.0), p1(10.0, 0.01, 0.0), p2(10.02, 0.0, 0.003);
  const glm::dvec3 a = glm::normalize(p0), b = glm::normalize(p1), c = glm::normalize(p2);
  const double area = sampling::SphericalTriangleArea(a, b, c);
  const glm::dvec3 centroid = (p0 + p1 + p2) / 3.0;
  const glm::dvec3 normal = glm::cross(p1 - p0, p2 - p0);
  const double planar =
      0.5 * std::abs(glm::dot(normal, glm::normalize(centroid))) / glm::dot(centroid, centroid);
  EXPECT_NEAR(area, planar, 1e-3 * planar);
  Pcg32 rng(7, 1);
  glm::dvec3 mean(0.0);
  for (int i = 0; i < 4096; ++i) mean += sampling::SphericalTriangle(a, b, c, area, rng.NextFloat(), rng.NextFloat());
  EXPECT_NEAR(glm::dot(glm::normalize(mean), glm::normalize(centroid)), 1.0, 1e-9);
}

// One value in each stratum, one point in each cell of the grid (the rest
// anywhere), and not in stratum order.
TEST(SamplingTest, StratifiedSamplesFillEveryStratumOnce) {
  Pcg32 rng(9, 2);
  const std::vector<float> values = Stratified1D(37, rng);
  ASSERT_EQ(values.size(), 37u);
  std::vector<int> perStratum(37);
  for (float v : values) {
    ASSERT_GE(v, 0.0f);
    ASSERT_LT(v, 1.0f);
    ++perStratum[size_t(v * 37.0f)];
  }
  for (int count : perStratum) EXPECT_EQ(count, 1);
  EXPECT_FALSE(std::is_sorted(values.begin(), values.end()));

  const std::vector<Vec2> points = Stratified2D(40, rng);  // a 6 x 6 grid and 4 more
  ASSERT_EQ(points.size(), 40u);
  std::vector<int> perCell(36);
  for (const Vec2& p : points) {
    ASSERT_TRUE(p.x >= 0.0f && p.x < 1.0f && p.y >= 0.0f && p.y < 1.0f);
    ++perCell[size_t(p.y * 6.0f) * 6 + size_t(p.x * 6.0f)];
  }
  int extra = 0;
  for (int count : perCell) {
    EXPECT_GE(count, 1);
    extra += count - 1;
  }
  EXPECT_EQ(extra, 4);
}

// JitteredGrid: point i in cell (i % g, i / g) of the g x g grid, the rest
// anywhere.
TEST(SamplingTest, JitteredGridFillsItsCellsInRowMajorOrder) {
  Pcg32 rng(4, 1);
  int cells = 0;
  const std::vector<Vec2> points = JitteredGrid(70, rng, &cells);  // an 8 x 8 grid and 6 more
  ASSERT_EQ(points.size(), 70u);
  ASSERT_EQ(cells, 64);
  for (int i = 0; i < 70; ++i) {
    const Vec2 p = points[size_t(i)];
    ASSERT_TRUE(p.x >= 0.0f && p.x < 1.0f && p.y >= 0.0f && p.y < 1.0f);
    if (i < 64) {
      EXPECT_EQ(int(p.x * 8.0f), i % 8) << i;
      EXPECT_EQ(int(p.y * 8.0f), i / 8) << i;
    }
  }
}

// The variance JitteredSumVariance estimates is the sum's over many draws:
// about right for a smooth integrand (a tilted plane plus a bump), and not
// below it for a discontinuous one (a disc's indicator, whose edge cells
// carry all the variance) -- where an independent samples' spread would
// overstate the smooth one's many times over.
TEST(SamplingTest, JitteredSumVarianceEstimatesTheStratifiedSumsSpread) {
  const auto smooth = [](Vec2 p) { return 1.0 + 0.8 * p.x - 0.5 * p.y + 0.3 * std::sin(6.0 * p.x); };
  const auto disc = [](Vec2 p) { return (p.x - 0.4) * (p.x - 0.4) + (p.y - 0.55) * (p.y - 0.55) < 0.09 ? 1.0 : 0.0; };
  for (int n : {8, 16, 64, 70}) {
    for (int which = 0; which < 2; ++which) {
      Pcg32 rng(11, uint64_t(n * 2 + which));
      constexpr int kDraws = 4000;
      double sum = 0.0, squares = 0.0, estimated = 0.0, independent = 0.0;
      for (int d = 0; d < kDraws; ++d) {
        int cells = 0;
        const std::vector<Vec2> points = JitteredGrid(n, rng, &cells);
        std::vector<double> values;
        for (const Vec2& p : points) values.push_back(which == 0 ? smooth(p) : disc(p));
        double total = 0.0, totalSquares = 0.0;
        for (double v : values) {
          total += v;
          totalSquares += v * v;
        }
        sum += total;
        squares += total * total;
        estimated += JitteredSumVariance(values, cells);
        independent += (totalSquares - total * total / n) * n / (n - 1);
      }
      const double actual = squares / kDraws - (sum / kDraws) * (sum / kDraws);
      const double ratio = estimated / kDraws / actual;
      SCOPED_TRACE(::testing::Message() << "n " << n << (which == 0 ? ", smooth" : ", disc") << ": estimated / actual "
                                        << ratio << ", independent samples' / actual " << independent / kDraws / actual);
      EXPECT_GT(ratio, 0.85);
      EXPECT_LT(ratio, which == 0 && n >= 64 ? 1.6 : 3.0);
      if (which == 0 && n == 64) {
        EXPECT_GT(independent / kDraws / actual, 10.0);
      }
    }
  }
}

TEST(SamplingTest, AliasTableDrawsInProportionToWeights) {
  const std::vector<double> weights = {1.0, 0.0, 3.0, 0.5, 10.0, 2.5, 0.0, 7.0};
  double sum = 0.0;
  for (double w : weights) sum += w;
  const AliasTable table(weights);
  ASSERT_EQ(table.size(), weights.size());
  Pcg32 rng(7, 8);
  std::vector<int> counts(weights.size(), 0);
  for (int i = 0; i < kN; ++i) ++counts[table.Sample(rng.NextFloat(), rng.NextFloat())];
  for (size_t i = 0; i < weights.size(); ++i) {
    const double p = weights[i] / sum;
    EXPECT_NEAR(counts[i], kN * p, 5.0 * std::sqrt(kN * p * (1.0 - p)) + 0.5) << "index " << i;
  }
}

TEST(SamplingTest, PowerHeuristicWeightsSumToOne) {
  EXPECT_FLOAT_EQ(PowerHeuristic(2.0f, 1.0f) + PowerHeuristic(1.0f, 2.0f), 1.0f);
  EXPECT_FLOAT_EQ(PowerHeuristic(3.0f, 0.0f), 1.0f);
  EXPECT_FLOAT_EQ(PowerHeuristic(1.0f, 1.0f), 0.5f);
}

}  // namespace
}  // namespace penumbra::sampling
