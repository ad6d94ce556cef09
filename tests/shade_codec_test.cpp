// The SMA's shade codec against the renderer's, in bytes: what the SMA
// encodes the renderer decodes to the same inputs, and what the renderer
// encodes the SMA decodes to the same samples; malformed replies are
// refused with a reason. A unit test: it links both tiers' libraries (the
// libraries themselves never include each other), no socket, no process.

#include <gtest/gtest.h>

#include <array>
#include <filesystem>
#include <string>
#include <vector>

#include "penumbra/common/framing.h"
#include "penumbra/common/messages.h"
#include "penumbra/common/scene.h"
#include "penumbra/renderer/shade_batch.h"
#include "penumbra/sma/hierarchy.h"
#include "penumbra/sma/shade_codec.h"

namespace penumbra {
namespace {

Scene LoadCornellBox() {
  auto scene = LoadScene(std::filesystem::path(PENUMBRA_SOURCE_DIR) / "scenes" / "cornell-box.json");
  if (!scene) ADD_FAILURE() << scene.error().message;
  return scene ? std::move(*scene) : Scene{};
}

// The bytes a peer would read: a frame's payload decoded as an envelope.
wire::Envelope FromFrame(const std::string& frame) {
  EXPECT_GT(frame.size(), kFrameHeaderBytes);
  auto envelope = DecodeEnvelope(std::string_view(frame).substr(kFrameHeaderBytes));
  EXPECT_TRUE(envelope) << (envelope ? "" : envelope.error().message);
  return envelope ? std::move(*envelope) : wire::Envelope{};
}

class ShadeCodec : public ::testing::Test {
 protected:
  ShadeCodec() : scene_(LoadCornellBox()), hierarchy_(scene_) {
    // Midpoints too, not only the scene's own vertices.
    for (sma::NodeId id = 0; id < 3; ++id) hierarchy_.Refine(id, sma::RefineOptions{});
    for (sma::VertexId v = 0; v < hierarchy_.VertexCount(); v += 3) {
      sma::SampleRequest r = sma::MakeSampleRequest(hierarchy_, v);
      r.round = uint16_t(v % 4 == 0 ? 0 : v % 7 + 1);  // first estimates and improvement rounds
      requests_.push_back(r);
    }
  }
  Scene scene_;
  sma::Hierarchy hierarchy_;
  std::vector<sma::SampleRequest> requests_;
};

TEST_F(ShadeCodec, WhatTheSmaEncodesTheRendererDecodes) {
  ASSERT_GT(requests_.size(), 10u);
  ASSERT_GT(hierarchy_.VertexCount(), hierarchy_.BaseVertexCount());
  const auto frame = sma::EncodeShadeRequestFrame(42, 16, requests_);
  const wire::Envelope envelope = FromFrame(*frame);
  ASSERT_TRUE(envelope.has_shade_request());
  EXPECT_EQ(envelope.shade_request().batch_id(), 42u);
  EXPECT_EQ(envelope.shade_request().paths_per_sample(), 16u);
  auto inputs = DecodeShadeRequest(envelope.shade_request(), scene_, ShadeLimits{});
  ASSERT_TRUE(inputs) << inputs.error().message;
  ASSERT_EQ(inputs->size(), requests_.size());
  for (size_t i = 0; i < requests_.size(); ++i) {
    const sma::SampleRequest& r = requests_[i];
    const ShadeInput& in = (*inputs)[i];
    EXPECT_EQ(in.sampleId, sma::WireSampleId(r.vertex, r.round));
    EXPECT_EQ(sma::VertexOfWireId(in.sampleId), r.vertex);
    EXPECT_EQ(sma::RoundOfWireId(in.sampleId), r.round);
    EXPECT_EQ(in.position, r.position);
    EXPECT_EQ(in.normal, r.normal);
    EXPECT_EQ(in.triangle, r.triangle);
    EXPECT_EQ(in.b1, r.bary.x);
    EXPECT_EQ(in.b2, r.bary.y);
  }
}

TEST_F(ShadeCodec, WhatTheRendererEncodesTheSmaDecodes) {
  const auto frame = sma::EncodeShadeRequestFrame(7, 0, requests_);
  auto inputs = DecodeShadeRequest(FromFrame(*frame).shade_request(), scene_, ShadeLimits{});
  ASSERT_TRUE(inputs) << inputs.error().message;
  std::vector<ShadeOutput> outputs(inputs->size());
  for (size_t i = 0; i < outputs.size(); ++i) {
    const float x = float(i) + 0.25f;
    outputs[i] = ShadeOutput{Rgb(x, 2 * x, 3 * x), Rgb(4 * x, 5 * x, 6 * x), 0.5f * x, uint32_t(16 + i)};
  }
  wire::Envelope reply;
  FillShadeReply(7, *inputs, outputs, 0, ShadeCounters{}, reply.mutable_shade_reply());
  const wire::Envelope received = FromFrame(EncodeEnvelopeFrame(reply));
  ASSERT_TRUE(received.has_shade_reply());
  auto samples = sma::DecodeShadeReply(received.shade_reply(), 64);
  ASSERT_TRUE(samples) << samples.error().message;
  ASSERT_EQ(samples->size(), requests_.size());
  for (size_t i = 0; i < samples->size(); ++i) {
    const sma::ShadedSample& s = (*samples)[i];
    EXPECT_EQ(s.vertex, requests_[i].vertex);
    EXPECT_EQ(s.round, requests_[i].round);
    EXPECT_EQ(s.radiance, outputs[i].radiance);
    EXPECT_EQ(s.irradiance, outputs[i].irradiance);
    EXPECT_EQ(s.irradianceStdErr, outputs[i].irradianceStdErr);
    EXPECT_EQ(s.paths, outputs[i].paths);  // the renderer's count, not the batch's
  }
  // A renderer that sends no path counts: the batch's count stands.
  reply.mutable_shade_reply()->clear_sample_paths();
  samples = sma::DecodeShadeReply(FromFrame(EncodeEnvelopeFrame(reply)).shade_reply(), 64);
  ASSERT_TRUE(samples) << samples.error().message;
  for (const auto& s : *samples) EXPECT_EQ(s.paths, 64u);
}

// A well-formed two-sample reply, as bytes, then spoiled one way each.
wire::ShadeReply GoodReply() {
  wire::ShadeReply r;
  r.set_batch_id(3);
  for (uint64_t id : {uint64_t(5), sma::WireSampleId(9, 2)}) {
    r.add_sample_ids(id);
    for (int k = 0; k < 3; ++k) r.add_radiance(0.5f);
    for (int k = 0; k < 3; ++k) r.add_irradiance(1.5f);
    r.add_irradiance_stderr(0.1f);
    r.add_sample_paths(32);
  }
  return r;
}

Expected<std::vector<sma::ShadedSample>> DecodeBytes(const wire::ShadeReply& reply) {
  wire::Envelope e;
  *e.mutable_shade_reply() = reply;
  return sma::DecodeShadeReply(FromFrame(EncodeEnvelopeFrame(e)).shade_reply(), 64);
}

TEST(ShadeCodecMalformed, RefusesEachBadReplyWithAReason) {
  ASSERT_TRUE(DecodeBytes(GoodReply()));
  EXPECT_EQ(DecodeBytes(GoodReply())->at(1).round, 2u);

  auto expectRefused = [](const wire::ShadeReply& r, const std::string& why) {
    auto decoded = DecodeBytes(r);
    ASSERT_FALSE(decoded) << "accepted: " << why;
    EXPECT_NE(decoded.error().message.find(why), std::string::npos) << decoded.error().message;
  };
  wire::ShadeReply r = GoodReply();
  r.mutable_radiance()->RemoveLast();
  expectRefused(r, "inconsistent arrays");
  r = GoodReply();
  r.add_irradiance_stderr(0.0f);
  expectRefused(r, "inconsistent arrays");
  r = GoodReply();
  r.mutable_sample_paths()->RemoveLast();  // neither none nor one each
  expectRefused(r, "inconsistent arrays");
  r = GoodReply();
  r.set_sample_paths(0, 0);
  expectRefused(r, "averages 0 paths");
  r = GoodReply();
  r.set_sample_paths(1, (1u << 24) + 1);
  expectRefused(r, "paths");
  r = GoodReply();
  r.set_sample_ids(1, 5);
  expectRefused(r, "answered twice");
  r = GoodReply();
  r.set_sample_ids(1, uint64_t(1) << 50);  // a round this SMA never asks for
  expectRefused(r, "names no round");

  // Bytes cut short: the envelope itself does not parse, or parses to a
  // reply the shape check refuses; never a sample from half a value.
  wire::Envelope e;
  *e.mutable_shade_reply() = GoodReply();
  const std::string frame = EncodeEnvelopeFrame(e);
  for (size_t cut = kFrameHeaderBytes + 1; cut < frame.size(); ++cut) {
    auto envelope = DecodeEnvelope(std::string_view(frame).substr(kFrameHeaderBytes, cut - kFrameHeaderBytes));
    if (!envelope || !envelope->has_shade_reply()) continue;
    auto decoded = sma::DecodeShadeReply(envelope->shade_reply(), 64);
    if (decoded) {
      EXPECT_LT(decoded->size(), 2u) << "cut at " << cut;
    }
  }
}


// Movable objects (issue 14): a batch carries its pose -- epoch and one
// transform per object -- and world positions and normals at it, for the
// object's samples as for the static part's.
TEST(ShadeCodecPose, ObjectSamplesGoInWorldSpaceAtTheBatchsPose) {
  SceneBuilder b;
  const uint32_t m = b.AddMaterial(Material{});
  b.AddQuad(Vec3(-2.0f, 0.0f, -2.0f), Vec3(0, 0, 4), Vec3(4, 0, 0), m);
  MovableObject box;
  box.name = "box";
  b.BeginObject(box);
  b.AddQuad(Vec3(-0.5f, 0.0f, -0.5f), Vec3(0, 0, 1), Vec3(1, 0, 0), m);
  b.EndObject();
  Scene scene;
  ASSERT_TRUE(b.BuildInto(scene).ok());
  sma::Hierarchy hierarchy(scene);
  std::vector<sma::SampleRequest> requests;
  for (sma::VertexId v = 0; v < hierarchy.VertexCount(); ++v) requests.push_back(sma::MakeSampleRequest(hierarchy, v));

  ScenePose pose = ScenePose::Initial(scene);
  pose.epoch = 9;
  pose.objectToWorld[0] = RigidTransform::FromAxisAngle(Vec3(1, 0, 0), 0.5f, Vec3(0.0f, 1.5f, 0.25f));
  const wire::Envelope envelope = FromFrame(*sma::EncodeShadeRequestFrame(3, 0, requests, &pose));
  const wire::ShadeRequest& r = envelope.shade_request();
  EXPECT_EQ(r.scene_epoch(), 9u);
  ASSERT_EQ(r.object_transforms_size(), 12);
  const std::array<float, 12> m12 = pose.objectToWorld[0].ToRowMajor();
  for (int i = 0; i < 12; ++i) EXPECT_EQ(r.object_transforms(i), m12[size_t(i)]);
  ASSERT_EQ(r.positions_size(), int(3 * requests.size()));
  size_t objectSamples = 0;
  for (size_t i = 0; i < requests.size(); ++i) {
    const sma::SampleVertex& sv = hierarchy.GetVertex(requests[i].vertex);
    const uint32_t object = scene.ObjectOfTriangle(sv.baseTriangle);
    EXPECT_EQ(requests[i].object, object);
    objectSamples += object != kStaticObject;
    const Vec3 world = WorldPointAt(scene, pose, sv.baseTriangle, sv.bary.x, sv.bary.y);
    const Vec3 worldNormal = pose.Of(object).ApplyVector(sv.normal);
    for (int k = 0; k < 3; ++k) {
      EXPECT_NEAR(r.positions(int(3 * i) + k), world[k], 1e-5f) << "sample " << i;
      EXPECT_NEAR(r.normals(int(3 * i) + k), worldNormal[k], 1e-5f) << "sample " << i;
    }
  }
  EXPECT_GT(objectSamples, 0u);

  // A static scene's batches carry epoch 0 and no transforms, as before.
  const wire::Envelope plain = FromFrame(*sma::EncodeShadeRequestFrame(4, 0, requests));
  EXPECT_EQ(plain.shade_request().scene_epoch(), 0u);
  EXPECT_EQ(plain.shade_request().object_transforms_size(), 0);
}

}  // namespace
}  // namespace penumbra
