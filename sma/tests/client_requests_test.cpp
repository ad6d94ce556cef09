// The SMA's message checks that need no session (client_requests.h) or no
// pool state (renderer_pool.h), as the server and the fuzz targets call them.

#include "penumbra/sma/client_requests.h"

#include <gtest/gtest.h>

#include "penumbra/sma/renderer_pool.h"
#include "penumbra/sma/texture_frames.h"

namespace penumbra::sma {
namespace {

void Set(wire::Vec3* v, float x, float y, float z) {
  v->set_x(x);
  v->set_y(y);
  v->set_z(z);
}

wire::View FrontView(uint32_t width, uint32_t height) {
  wire::View v;
  v.set_view_id(3);
  Set(v.mutable_eye(), 0.0f, 1.0f, 3.9f);
  Set(v.mutable_target(), 0.0f, 1.0f, 0.0f);
  Set(v.mutable_up(), 0.0f, 1.0f, 0.0f);
  v.set_fov_y_deg(40.0f);
  v.set_width(width);
  v.set_height(height);
  return v;
}

TEST(ClientRequestsTest, ViewFromWireKeepsTheViewAndRefusesBadOrTooLargeOnes) {
  auto view = ViewFromWire(FrontView(640, 480), 640 * 480);
  ASSERT_TRUE(view.ok()) << view.error().message;
  EXPECT_EQ(view->width, 640);
  EXPECT_EQ(view->height, 480);
  EXPECT_FLOAT_EQ(view->pose.eye.z, 3.9f);

  auto large = ViewFromWire(FrontView(641, 480), 640 * 480);
  ASSERT_FALSE(large.ok());
  EXPECT_EQ(large.error().message, "view 3: 641x480 pixels; this SMA serves at most 307200 per view");

  wire::View far = FrontView(64, 64);
  Set(far.mutable_eye(), 1e19f, 1.0f, 3.9f);  // beyond Embree's range (issue 12, item 1)
  auto refused = ViewFromWire(far, 1u << 20);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.error().message.rfind("view 3: ", 0), 0u) << refused.error().message;
}

TEST(ClientRequestsTest, TexturesAreNamedInRangeAndDownscaledToTheBudget) {
  wire::TextureRequest request;
  request.set_texture(2);
  EXPECT_FALSE(CheckTextureRequest(request, 2).ok());
  EXPECT_TRUE(CheckTextureRequest(request, 3).ok());

  Texture t;
  t.width = 8;
  t.height = 4;
  t.texels.assign(32, Rgb(1.0f));
  const wire::TextureData whole = EncodeTextureData(t, 2, 1000);
  EXPECT_EQ(whole.texture(), 2u);
  EXPECT_EQ(whole.width(), 8u);
  EXPECT_EQ(whole.rgb8(), std::string(8 * 4 * 3, char(255)));
  const wire::TextureData halved = EncodeTextureData(t, 2, 8 * 4 * 3 - 1);
  EXPECT_EQ(halved.width(), 4u);
  EXPECT_EQ(halved.height(), 2u);
  EXPECT_EQ(halved.rgb8().size(), 4u * 2u * 3u);
}

TEST(ShadeReplyChecksTest, ArraysMustAgreeAndPathCountsBeInRange) {
  wire::ShadeReply reply;
  reply.add_sample_ids((uint64_t(2) << 32) | 7);  // vertex 7, improvement round 2
  for (float v : {0.1f, 0.2f, 0.3f}) reply.add_radiance(v);
  for (float v : {1.0f, 2.0f, 3.0f}) reply.add_irradiance(v);
  EXPECT_FALSE(CheckShadeReplyShape(reply).ok());  // no standard error yet
  reply.add_irradiance_stderr(0.01f);
  ASSERT_TRUE(CheckShadeReplyShape(reply).ok());

  auto sample = DecodeReplySample(reply, 0, 64);
  ASSERT_TRUE(sample.ok()) << sample.error().message;
  EXPECT_EQ(sample->vertex, VertexId(7));
  EXPECT_EQ(sample->round, 2);
  EXPECT_EQ(sample->paths, 64u);  // the batch's, as the reply names none
  EXPECT_FLOAT_EQ(sample->irradiance.b, 3.0f);

  reply.add_sample_paths(0);
  ASSERT_TRUE(CheckShadeReplyShape(reply).ok());
  auto none = DecodeReplySample(reply, 0, 64);
  ASSERT_FALSE(none.ok());
  EXPECT_EQ(none.error().message, "sample 8589934599 averages 0 paths");
  reply.add_sample_paths(5);  // two path counts for one sample
  EXPECT_FALSE(CheckShadeReplyShape(reply).ok());
}

}  // namespace
}  // namespace penumbra::sma
