#pragma once
// The scene the refinement tests refine: a 6 x 6 grid of unit quads on the
// y = 0 plane, seen from above by a kImage-pixel view, with a hard shadow
// edge at x = kShadowEdgeX that crosses cells and touches no vertex.

#include <gtest/gtest.h>

#include "penumbra/common/scene.h"

namespace penumbra::sma {

inline constexpr float kShadowEdgeX = 3.3f;  // lit for x < 3.3, in shadow beyond
inline constexpr int kGrid = 6;
inline constexpr int kImage = 96;

inline Scene GridScene() {
  SceneBuilder b;
  Material m;
  m.albedo = Rgb(0.5f);
  const uint32_t mat = b.AddMaterial(m);
  for (int i = 0; i < kGrid; ++i)
    for (int j = 0; j < kGrid; ++j) b.AddQuad(Vec3(float(i), 0, float(j)), Vec3(0, 0, 1), Vec3(1, 0, 0), mat);
  Scene s;
  s.twoSided = false;  // one surface per triangle; two-sided hierarchies have tests of their own
  EXPECT_TRUE(b.BuildInto(s).ok());
  return s;
}

}  // namespace penumbra::sma
