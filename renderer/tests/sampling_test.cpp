// Moments of the sampling warps against their closed forms. Each check
// averages N samples and allows 5 standard deviations of that mean, from the
// known variance of the sampled quantity.

#include "sampling.h"

#include <gtest/gtest.h>

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
