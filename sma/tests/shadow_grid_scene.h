#pragma once
// The scene the refinement tests refine: a 6 x 6 grid of unit quads on the
// y = 0 plane, seen from above by a kImage-pixel view, with a hard shadow
// edge at x = kShadowEdgeX that crosses cells and touches no vertex.

#include <gtest/gtest.h>

#include "hierarchy_test_scenes.h"
#include "penumbra/common/scene.h"

namespace penumbra::sma {

inline constexpr float kShadowEdgeX = 3.3f;  // lit for x < 3.3, in shadow beyond
inline constexpr int kGrid = 6;
inline constexpr int kImage = 96;

inline Scene GridScene() {
  Scene s = GridScene(kGrid);  // hierarchy_test_scenes.h: one-sided, 2 triangles per cell
  for (Material& m : s.materials) m.albedo = Rgb(0.5f);
  return s;
}

}  // namespace penumbra::sma
