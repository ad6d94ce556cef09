// MeasureRasterLoad: a quad's screen area against the perspective's analytic
// value, empty slots drawn but not covered, a triangle through the eye plane
// counted as the viewport.

#include "penumbra/client/raster_load.h"

#include <vector>

#include <gtest/gtest.h>

#include "penumbra/client/projection.h"
#include "support/delta_builder.h"

namespace penumbra::client {
namespace {

using testing::DeltaBuilder;

class RasterLoadTest : public ::testing::Test {
 protected:
  void SetUp() override {
    store_.Reset(std::vector<int32_t>{-1}, 0);
    // 90 degrees vertical field of view from 3 m: the viewport spans +-3 m
    // at z = 0, so a 2 m quad there is a third of its width and height.
    view_.pose = CameraPose{Vec3(0, 0, 3), Vec3(0, 0, 0), Vec3(0, 1, 0)};
    view_.fovYDeg = 90.0f;
    view_.width = 120;
    view_.height = 120;
    bounds_.Extend(Vec3(-5, -5, -5));
    bounds_.Extend(Vec3(5, 5, 5));
  }
  RasterLoad Measure() const { return MeasureRasterLoad(store_, WorldToClip(view_, bounds_), view_.width, view_.height); }

  MeshStore store_;
  CameraView view_;
  Bounds3 bounds_;
};

TEST_F(RasterLoadTest, AQuadFacingTheCameraCoversItsProjectedArea) {
  DeltaBuilder d(1, 1);
  d.Vertex(1, Vec3(-1, -1, 0), Rgb(1.0f)).Vertex(2, Vec3(1, -1, 0), Rgb(1.0f));
  d.Vertex(3, Vec3(1, 1, 0), Rgb(1.0f)).Vertex(4, Vec3(-1, 1, 0), Rgb(1.0f));
  d.Triangle(10, {1, 2, 3}, 0).Triangle(11, {1, 3, 4}, 0);
  ASSERT_TRUE(store_.Apply(d.Delta()).ok());
  const RasterLoad load = Measure();
  EXPECT_EQ(load.slotsDrawn, 2u);
  EXPECT_EQ(load.trianglesLive, 2u);
  EXPECT_EQ(load.trianglesCrossingEyePlane, 0u);
  EXPECT_NEAR(load.coveredPixels, 40.0 * 40.0, 1.0);  // (120 / 3)^2
  EXPECT_NEAR(load.largestPixels, 800.0, 0.5);

  // A removed triangle's slot is still drawn (as nothing) and covers nothing.
  ASSERT_TRUE(store_.Apply(DeltaBuilder(2, 1).Remove(11).Delta()).ok());
  const RasterLoad after = Measure();
  EXPECT_EQ(after.slotsDrawn, 2u);
  EXPECT_EQ(after.trianglesLive, 1u);
  EXPECT_NEAR(after.coveredPixels, 800.0, 0.5);
  EXPECT_NE(Describe(after, view_.width, view_.height).find("2 triangle slots drawn, 1 live"), std::string::npos)
      << Describe(after, view_.width, view_.height);
}

TEST_F(RasterLoadTest, ATriangleOffScreenCoversNothingAndOneThroughTheEyePlaneTheViewport) {
  DeltaBuilder d(1, 1);
  // Beside the view, in front of the camera: outside the viewport.
  d.Vertex(1, Vec3(20, 0, 0), Rgb(1.0f)).Vertex(2, Vec3(22, 0, 0), Rgb(1.0f)).Vertex(3, Vec3(21, 1, 0), Rgb(1.0f));
  // From in front of the eye to behind it.
  d.Vertex(4, Vec3(-1, -1, 0), Rgb(1.0f)).Vertex(5, Vec3(1, -1, 0), Rgb(1.0f)).Vertex(6, Vec3(0, -1, 4), Rgb(1.0f));
  d.Triangle(10, {1, 2, 3}, 0).Triangle(11, {4, 5, 6}, 0);
  ASSERT_TRUE(store_.Apply(d.Delta()).ok());
  const RasterLoad load = Measure();
  EXPECT_EQ(load.trianglesLive, 2u);
  EXPECT_EQ(load.trianglesCrossingEyePlane, 1u);
  EXPECT_DOUBLE_EQ(load.coveredPixels, 120.0 * 120.0);
  EXPECT_FLOAT_EQ(load.largestCorners[2].z, 4.0f);
}

}  // namespace
}  // namespace penumbra::client
