// ChunkedArray: the hierarchy's node and vertex tables.

#include "penumbra/sma/chunked_array.h"

#include <gtest/gtest.h>

#include <cstdint>

namespace penumbra::sma {
namespace {

TEST(ChunkedArrayTest, GrowsByWholeChunksWithoutMovingElements) {
  ChunkedArray<uint64_t, 4> a;  // 16 per chunk
  EXPECT_TRUE(a.empty());
  EXPECT_EQ(a.capacity(), 0u);
  a.push_back(7);
  const uint64_t* first = &a[0];
  for (uint64_t i = 1; i < 100; ++i) a.push_back(7 + i);
  EXPECT_EQ(a.size(), 100u);
  EXPECT_EQ(a.capacity(), 112u) << "7 chunks of 16: never more than one chunk ahead";
  EXPECT_EQ(&a[0], first) << "growth never moves an element";
  for (uint64_t i = 0; i < 100; ++i) ASSERT_EQ(a[i], 7 + i) << i;
}

TEST(ChunkedArrayTest, ResizeValueInitialisesAndOnlyGrows) {
  struct Point {
    int x = -1;
    float y = 0.5f;
  };
  ChunkedArray<Point, 3> a;  // 8 per chunk
  a.push_back(Point{3, 1.0f});
  a.resize(20);
  EXPECT_EQ(a.size(), 20u);
  EXPECT_EQ(a.capacity(), 24u);
  EXPECT_EQ(a[0].x, 3);
  for (size_t i = 1; i < 20; ++i) {
    EXPECT_EQ(a[i].x, -1) << i;
    EXPECT_EQ(a[i].y, 0.5f) << i;
  }
  a.push_back(Point{9, 2.0f});
  EXPECT_EQ(a[20].x, 9);
  EXPECT_GE(a.MemoryBytes(), 24 * sizeof(Point));
  EXPECT_DEATH(a.resize(3), "only grows");
}

}  // namespace
}  // namespace penumbra::sma
