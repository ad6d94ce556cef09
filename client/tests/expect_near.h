#pragma once
// Vector comparison shared by the client core's tests.

#include <gtest/gtest.h>

#include "penumbra/common/math.h"

namespace penumbra::client {

inline void ExpectNear(const Vec3& got, const Vec3& expected, float tolerance = 1e-5f) {
  EXPECT_NEAR(got.x, expected.x, tolerance);
  EXPECT_NEAR(got.y, expected.y, tolerance);
  EXPECT_NEAR(got.z, expected.z, tolerance);
}

}  // namespace penumbra::client
