// SlotAllocator and DirtyRanges: free-list reuse and range merging.

#include "penumbra/client/slots.h"

#include <gtest/gtest.h>

namespace penumbra::client {
namespace {

TEST(SlotAllocatorTest, ReusesReleasedSlotsBeforeGrowing) {
  SlotAllocator slots;
  EXPECT_EQ(slots.Allocate(), 0u);
  EXPECT_EQ(slots.Allocate(), 1u);
  EXPECT_EQ(slots.Allocate(), 2u);
  slots.Release(0);
  slots.Release(2);
  EXPECT_EQ(slots.Live(), 1u);
  EXPECT_EQ(slots.Allocate(), 2u) << "most recently released first";
  EXPECT_EQ(slots.Allocate(), 0u);
  EXPECT_EQ(slots.Allocate(), 3u);
  EXPECT_EQ(slots.HighWater(), 4u);
  EXPECT_EQ(slots.Live(), 4u);
  slots.Clear();
  EXPECT_EQ(slots.HighWater(), 0u);
  EXPECT_EQ(slots.Allocate(), 0u);
}

TEST(DirtyRangesTest, SortsMergesAndForgets) {
  DirtyRanges dirty;
  EXPECT_TRUE(dirty.Empty());
  for (uint32_t s : {7u, 3u, 4u, 5u, 4u, 10u}) dirty.Mark(s);
  EXPECT_EQ(dirty.Take(), (std::vector<SlotRange>{{3, 3}, {7, 1}, {10, 1}}));
  EXPECT_TRUE(dirty.Empty());
  EXPECT_TRUE(dirty.Take().empty());
}

TEST(DirtyRangesTest, MergesAcrossSmallGaps) {
  DirtyRanges dirty;
  for (uint32_t s : {1u, 3u, 10u}) dirty.Mark(s);
  EXPECT_EQ(dirty.Take(/*mergeGap=*/1), (std::vector<SlotRange>{{1, 3}, {10, 1}}));
  for (uint32_t s : {1u, 3u, 10u}) dirty.Mark(s);
  EXPECT_EQ(dirty.Take(/*mergeGap=*/6), (std::vector<SlotRange>{{1, 10}}));
}

}  // namespace
}  // namespace penumbra::client
