#include "penumbra/client/progress.h"

#include <gtest/gtest.h>

namespace penumbra::client {
namespace {

using namespace std::chrono_literals;

TEST(ProgressRateTest, MeasuresTheRateAndTheTimeLeft) {
  ProgressRate rate(1000ms);
  const auto t0 = ProgressRate::Clock::time_point{};
  rate.Update(0, 1000, t0);
  EXPECT_FALSE(rate.PerSecond());
  EXPECT_FALSE(rate.TimeLeft());
  rate.Update(100, 1000, t0 + 1s);  // 100 per second
  ASSERT_TRUE(rate.PerSecond());
  EXPECT_NEAR(*rate.PerSecond(), 100.0, 1e-9);
  ASSERT_TRUE(rate.TimeLeft());
  EXPECT_EQ(rate.TimeLeft()->count(), 9);  // 900 left at 100/s
  for (int i = 2; i <= 6; ++i) rate.Update(100 * uint64_t(i), 1000, t0 + std::chrono::seconds(i));
  EXPECT_NEAR(*rate.PerSecond(), 100.0, 1e-6);
  EXPECT_EQ(rate.TimeLeft()->count(), 4);
}

TEST(ProgressRateTest, ARestartedCountStartsOver) {
  ProgressRate rate;
  const auto t0 = ProgressRate::Clock::time_point{};
  rate.Update(0, 100, t0);
  rate.Update(50, 100, t0 + 1s);
  ASSERT_TRUE(rate.PerSecond());
  rate.Update(10, 400, t0 + 2s);  // a new view
  EXPECT_FALSE(rate.PerSecond());
  EXPECT_FALSE(rate.TimeLeft());
}

TEST(ProgressRateTest, NothingLeftOrNoProgressHasNoTimeLeft) {
  ProgressRate rate;
  const auto t0 = ProgressRate::Clock::time_point{};
  rate.Update(0, 100, t0);
  rate.Update(0, 100, t0 + 1s);
  EXPECT_FALSE(rate.TimeLeft());  // stalled: no renderer, say
  rate.Update(100, 100, t0 + 2s);
  EXPECT_FALSE(rate.TimeLeft());
}

TEST(ProgressTextTest, CountsAndDurationsCarryTheirUnits) {
  EXPECT_EQ(FormatCount(0), "0");
  EXPECT_EQ(FormatCount(999), "999");
  EXPECT_EQ(FormatCount(1000), "1,000");
  EXPECT_EQ(FormatCount(1234567), "1,234,567");
  EXPECT_EQ(FormatDuration(45s), "45 s");
  EXPECT_EQ(FormatDuration(125s), "2 min 05 s");
  EXPECT_EQ(FormatDuration(3725s), "1 h 02 min");
  EXPECT_EQ(FormatBytesPerSecond(850), "850 B/s");
  EXPECT_EQ(FormatBytesPerSecond(12345), "12.3 kB/s");
}

}  // namespace
}  // namespace penumbra::client
