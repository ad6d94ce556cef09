// The SMA's shade codec against the renderer's, in bytes: what the SMA
// encodes the renderer decodes to the same inputs, and what the renderer
// encodes the SMA decodes to the same samples; malformed replies are
// refused with a reason. A unit test: it links both tiers' libraries (the
// libraries themselves never include each other), no socket, no process.

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <filesystem>
#include <limits>
#include <memory>
#include <span>
#include <string>
#include <utility>
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
  EXPECT_FALSE(envelope.shade_request().urgent());
  EXPECT_TRUE(FromFrame(*sma::EncodeShadeRequestFrame(43, 16, requests_, nullptr, /*urgent=*/true)).shade_request().urgent())
      << "what a client waits for is marked so";
  EXPECT_FALSE(envelope.shade_request().soon());
  const wire::Envelope soon = FromFrame(*sma::EncodeShadeRequestFrame(44, 16, requests_, nullptr, false, /*soon=*/true));
  EXPECT_TRUE(soon.shade_request().soon() && !soon.shade_request().urgent()) << "what a client is expected to want";
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

// --- Verification batches (a move's test; issue 14) -------------------------------

// A static floor and back wall and `boxes` movable boxes (one quad each,
// "box0", "box1", ...) standing on the floor.
Scene SceneWithBoxes(int boxes) {
  SceneBuilder b;
  const uint32_t m = b.AddMaterial(Material{});
  b.AddQuad(Vec3(-4.0f, 0.0f, -4.0f), Vec3(0, 0, 8), Vec3(8, 0, 0), m);  // the floor, facing up
  b.AddQuad(Vec3(-4.0f, 0.0f, -4.0f), Vec3(8, 0, 0), Vec3(0, 3, 0), m);  // the back wall, facing +z
  for (int i = 0; i < boxes; ++i) {
    MovableObject box;
    box.name = "box" + std::to_string(i);
    box.objectToWorld = RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.0f, Vec3(-3.0f + 0.75f * float(i), 0.5f, 0.0f));
    b.BeginObject(box);
    b.AddQuad(Vec3(-0.25f, 0.0f, -0.25f), Vec3(0, 0, 0.5f), Vec3(0.5f, 0, 0), m);
    b.EndObject();
  }
  Scene scene;
  const Status built = b.BuildInto(scene);
  EXPECT_TRUE(built.ok()) << (built.ok() ? "" : built.error().message);
  return scene;
}

void ExpectSamePlaces(const ScenePose& actual, const ScenePose& expected) {
  ASSERT_EQ(actual.objectToWorld.size(), expected.objectToWorld.size());
  for (size_t o = 0; o < expected.objectToWorld.size(); ++o) {
    const std::array<float, 12> a = actual.objectToWorld[o].ToRowMajor(), e = expected.objectToWorld[o].ToRowMajor();
    for (size_t i = 0; i < 12; ++i) EXPECT_NEAR(a[i], e[i], 1e-6f) << "object " << o << ", value " << i;
  }
}

class ShadeCodecVerify : public ::testing::Test {
 protected:
  ShadeCodecVerify() : scene_(SceneWithBoxes(2)), hierarchy_(scene_) {
    baseline_ = std::make_shared<ScenePose>(ScenePose::Initial(scene_));
    baseline_->epoch = 4;
    baseline_->objectToWorld[0] = RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.0f, Vec3(-1.0f, 0.5f, 1.0f));
    target_ = std::make_shared<ScenePose>(*baseline_);
    target_->epoch = 6;
    target_->objectToWorld[0] = RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.7f, Vec3(1.5f, 0.5f, -0.5f));
    // Only static samples are tested: a moving object's own are shaded again.
    for (sma::VertexId v = 0; v < hierarchy_.VertexCount(); ++v) {
      sma::SampleRequest r = sma::MakeSampleRequest(hierarchy_, v);
      if (r.object != kStaticObject) continue;
      r.round = sma::VerifyRound(target_->epoch);
      requests_.push_back(r);
    }
  }
  Scene scene_;
  sma::Hierarchy hierarchy_;
  std::shared_ptr<ScenePose> baseline_, target_;
  std::vector<sma::SampleRequest> requests_;
};

TEST_F(ShadeCodecVerify, RegionBoxesHoldEachMovedObjectAtBothPosesAndNothingWhenNothingMoved) {
  auto boxes = sma::VerifyRegionBoxes(scene_, *baseline_, *target_);
  ASSERT_TRUE(boxes.has_value());
  ASSERT_EQ(boxes->size(), 2u) << "box0 moved, box1 did not";
  EXPECT_EQ((*boxes)[0].min, WorldBounds(scene_, *baseline_, 0).min);
  EXPECT_EQ((*boxes)[0].max, WorldBounds(scene_, *baseline_, 0).max);
  EXPECT_EQ((*boxes)[1].min, WorldBounds(scene_, *target_, 0).min);
  EXPECT_EQ((*boxes)[1].max, WorldBounds(scene_, *target_, 0).max);
  EXPECT_NE((*boxes)[0].min, (*boxes)[1].min) << "two boxes, not one";

  // Both moved: two boxes each, in object order.
  ScenePose both = *target_;
  both.objectToWorld[1] = RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.0f, Vec3(2.0f, 0.5f, 2.0f));
  boxes = sma::VerifyRegionBoxes(scene_, *baseline_, both);
  ASSERT_TRUE(boxes.has_value());
  ASSERT_EQ(boxes->size(), 4u);
  EXPECT_EQ((*boxes)[2].min, WorldBounds(scene_, *baseline_, 1).min);
  EXPECT_EQ((*boxes)[3].max, WorldBounds(scene_, both, 1).max);

  // Nothing placed differently (whatever the epochs): nothing to test through.
  ScenePose same = *baseline_;
  same.epoch = 9;
  EXPECT_FALSE(sma::VerifyRegionBoxes(scene_, *baseline_, same).has_value());
  EXPECT_FALSE(sma::VerifyRegionBoxes(scene_, *baseline_, *baseline_).has_value());
}

TEST(ShadeCodecVerifyBoxes, MoreBoxesThanARendererTakesAreNone) {
  const Scene scene = SceneWithBoxes(9);
  ASSERT_EQ(scene.objects.size(), 9u);
  const ScenePose initial = ScenePose::Initial(scene);
  ScenePose moved = initial;
  for (size_t o = 0; o < 8; ++o) moved.objectToWorld[o].translation.z += 1.0f;
  auto boxes = sma::VerifyRegionBoxes(scene, initial, moved);
  ASSERT_TRUE(boxes.has_value());
  EXPECT_EQ(boxes->size(), sma::kMaxVerifyBoxes) << "eight objects: sixteen boxes, the limit";
  moved.objectToWorld[8].translation.z += 1.0f;
  EXPECT_FALSE(sma::VerifyRegionBoxes(scene, initial, moved).has_value()) << "eighteen boxes";
  static_assert(sma::kMaxVerifyBoxes == kMaxVerificationBoxes, "the SMA's limit is the renderer's");
}

TEST_F(ShadeCodecVerify, WhatTheSmaEncodesTheRendererDecodesWithTheBaselineAndTheBoxes) {
  ASSERT_GT(requests_.size(), 4u);
  ASSERT_LT(requests_.size(), size_t(hierarchy_.VertexCount())) << "the boxes' own are left out";
  auto boxes = sma::VerifyRegionBoxes(scene_, *baseline_, *target_);
  ASSERT_TRUE(boxes.has_value());
  const sma::VerifyContext context{baseline_, target_, *boxes};
  const wire::Envelope envelope = FromFrame(*sma::EncodeVerifyRequestFrame(11, 64, requests_, context));
  ASSERT_TRUE(envelope.has_shade_request());
  const wire::ShadeRequest& request = envelope.shade_request();
  EXPECT_EQ(request.batch_id(), 11u);
  EXPECT_EQ(request.paths_per_sample(), 64u);
  EXPECT_EQ(request.scene_epoch(), 6u) << "shaded at the target pose";
  ASSERT_TRUE(request.has_verify_change());
  // FillVerifyRequest is what the frame carries.
  wire::ShadeRequest filled;
  sma::FillVerifyRequest(11, 64, requests_, context, &filled);
  EXPECT_EQ(filled.SerializeAsString(), request.SerializeAsString());

  auto pose = DecodeShadePose(request, scene_);
  ASSERT_TRUE(pose) << pose.error().message;
  EXPECT_EQ(pose->epoch, 6u);
  ExpectSamePlaces(*pose, *target_);
  auto inputs = DecodeShadeRequest(request, scene_, *pose, ShadeLimits{});
  ASSERT_TRUE(inputs) << inputs.error().message;
  ASSERT_EQ(inputs->size(), requests_.size());
  for (size_t i = 0; i < requests_.size(); ++i) {
    const sma::SampleRequest& r = requests_[i];
    EXPECT_EQ((*inputs)[i].sampleId, sma::WireSampleId(r.vertex, sma::VerifyRound(6)));
    EXPECT_EQ((*inputs)[i].position, r.position) << "a static sample: world space as it is";
    EXPECT_EQ((*inputs)[i].normal, r.normal);
    EXPECT_EQ((*inputs)[i].triangle, r.triangle);
  }
  auto verification = DecodeVerifyChange(request, scene_, *inputs);
  ASSERT_TRUE(verification) << verification.error().message;
  EXPECT_EQ(verification->baseline.epoch, 4u);
  ExpectSamePlaces(verification->baseline, *baseline_);
  ASSERT_EQ(verification->region.size(), boxes->size());
  for (size_t b = 0; b < boxes->size(); ++b) {
    EXPECT_EQ(verification->region[b].min, (*boxes)[b].min) << b;
    EXPECT_EQ(verification->region[b].max, (*boxes)[b].max) << b;
  }

  // A baseline at the scene's initial pose, epoch 0, decodes too.
  const sma::VerifyContext fromStart{std::make_shared<ScenePose>(ScenePose::Initial(scene_)), target_, *boxes};
  const wire::Envelope start = FromFrame(*sma::EncodeVerifyRequestFrame(12, 64, requests_, fromStart));
  verification = DecodeVerifyChange(start.shade_request(), scene_, *inputs);
  ASSERT_TRUE(verification) << verification.error().message;
  EXPECT_EQ(verification->baseline.epoch, 0u);
  ExpectSamePlaces(verification->baseline, ScenePose::Initial(scene_));
}

TEST_F(ShadeCodecVerify, WhatTheRendererAnswersTheSmaDecodes) {
  auto boxes = sma::VerifyRegionBoxes(scene_, *baseline_, *target_);
  ASSERT_TRUE(boxes.has_value());
  const sma::VerifyContext context{baseline_, target_, *boxes};
  const wire::Envelope envelope = FromFrame(*sma::EncodeVerifyRequestFrame(11, 64, requests_, context));
  auto inputs = DecodeShadeRequest(envelope.shade_request(), scene_, ShadeLimits{});
  ASSERT_TRUE(inputs) << inputs.error().message;
  std::vector<ChangeEstimate> changes(inputs->size());
  for (size_t i = 0; i < changes.size(); ++i) {
    const float x = float(i) + 0.25f;
    changes[i].irradianceChange = i % 2 ? -x : x;  // darker and brighter
    changes[i].standardError = 0.125f * x;
    changes[i].paths = 64;
  }
  // In two parts, as a renderer may send it.
  const size_t half = inputs->size() / 2;
  std::vector<sma::VerifiedSample> decoded;
  std::vector<uint16_t> rounds;
  for (const auto& [begin, end] : {std::pair{size_t(0), half}, std::pair{half, inputs->size()}}) {
    wire::Envelope reply;
    FillChangeReply(11, std::span(*inputs).subspan(begin, end - begin), std::span(changes).subspan(begin, end - begin),
                    uint32_t(inputs->size() - end), ShadeCounters{}, reply.mutable_shade_reply());
    reply.mutable_shade_reply()->set_scene_epoch(6);
    const wire::Envelope received = FromFrame(EncodeEnvelopeFrame(reply));
    ASSERT_TRUE(received.has_shade_reply());
    EXPECT_EQ(received.shade_reply().remaining(), inputs->size() - end);
    auto part = sma::DecodeVerifyReply(received.shade_reply(), &rounds);
    ASSERT_TRUE(part) << part.error().message;
    EXPECT_EQ(part->size(), end - begin);
    decoded.insert(decoded.end(), part->begin(), part->end());
  }
  ASSERT_EQ(decoded.size(), requests_.size());
  ASSERT_EQ(rounds.size(), requests_.size()) << "one round per sample, parallel";
  for (size_t i = 0; i < decoded.size(); ++i) {
    SCOPED_TRACE(i);
    EXPECT_EQ(decoded[i].vertex, requests_[i].vertex);
    EXPECT_EQ(rounds[i], sma::VerifyRound(6));
    EXPECT_EQ(decoded[i].change, changes[i].irradianceChange);
    EXPECT_EQ(decoded[i].changeStdErr, changes[i].standardError);
    EXPECT_EQ(decoded[i].generation, 0u) << "the scheduler's to fill";
    EXPECT_EQ(decoded[i].targetEpoch, 0u);
  }
  // The rounds are optional.
  wire::ShadeReply whole;
  FillChangeReply(11, *inputs, changes, 0, ShadeCounters{}, &whole);
  auto again = sma::DecodeVerifyReply(whole, nullptr);
  ASSERT_TRUE(again) << again.error().message;
  EXPECT_EQ(again->size(), requests_.size());
}

// A well-formed two-sample verification reply, then spoiled one way each.
wire::ShadeReply GoodChangeReply() {
  wire::ShadeReply r;
  r.set_batch_id(3);
  r.set_scene_epoch(3);
  for (uint64_t id : {sma::WireSampleId(5, sma::VerifyRound(3)), sma::WireSampleId(9, sma::VerifyRound(3))}) {
    r.add_sample_ids(id);
    r.add_irradiance_change(-0.5f);
    r.add_irradiance_change_stderr(0.1f);
  }
  return r;
}

Expected<std::vector<sma::VerifiedSample>> DecodeChangeBytes(const wire::ShadeReply& reply,
                                                               std::vector<uint16_t>* rounds = nullptr) {
  wire::Envelope e;
  *e.mutable_shade_reply() = reply;
  return sma::DecodeVerifyReply(FromFrame(EncodeEnvelopeFrame(e)).shade_reply(), rounds);
}

TEST(ShadeCodecMalformed, RefusesEachBadVerificationReplyWithAReason) {
  std::vector<uint16_t> rounds;
  auto good = DecodeChangeBytes(GoodChangeReply(), &rounds);
  ASSERT_TRUE(good) << good.error().message;
  ASSERT_EQ(good->size(), 2u);
  EXPECT_EQ((*good)[1].vertex, 9u);
  EXPECT_EQ((*good)[1].change, -0.5f);
  EXPECT_EQ(rounds, (std::vector<uint16_t>{sma::VerifyRound(3), sma::VerifyRound(3)}));

  auto expectRefused = [](const wire::ShadeReply& r, const std::string& why) {
    std::vector<uint16_t> partRounds;
    auto decoded = DecodeChangeBytes(r, &partRounds);
    ASSERT_FALSE(decoded) << "accepted: " << why;
    EXPECT_NE(decoded.error().message.find(why), std::string::npos) << decoded.error().message;
  };
  wire::ShadeReply r = GoodChangeReply();
  r.mutable_irradiance_change()->RemoveLast();
  expectRefused(r, "inconsistent verification arrays");
  r = GoodChangeReply();
  r.add_irradiance_change_stderr(0.0f);
  expectRefused(r, "inconsistent verification arrays");
  r = GoodChangeReply();
  r.mutable_sample_ids()->RemoveLast();
  expectRefused(r, "inconsistent verification arrays");
  r = GoodChangeReply();
  for (int k = 0; k < 6; ++k) r.add_radiance(0.5f);  // a shading answer's values too
  expectRefused(r, "inconsistent verification arrays");
  r = GoodChangeReply();
  for (int k = 0; k < 6; ++k) r.add_irradiance(0.5f);
  expectRefused(r, "inconsistent verification arrays");
  r = GoodChangeReply();
  r.set_sample_ids(1, r.sample_ids(0));
  expectRefused(r, "answered twice");
  r = GoodChangeReply();
  r.set_sample_ids(1, uint64_t(1) << 50);
  expectRefused(r, "names no round");
  r = GoodChangeReply();
  r.set_irradiance_change_stderr(1, -0.01f);
  expectRefused(r, "impossible");
  r = GoodChangeReply();
  r.set_irradiance_change(0, std::nanf(""));
  expectRefused(r, "impossible");
  r = GoodChangeReply();
  r.set_irradiance_change(1, std::numeric_limits<float>::infinity());
  expectRefused(r, "impossible");
  r = GoodChangeReply();
  r.set_irradiance_change_stderr(0, std::nanf(""));
  expectRefused(r, "impossible");
}

TEST(ShadeCodecVerifyRound, EachTargetEpochHasARoundAboveEveryImprovement) {
  EXPECT_TRUE(sma::IsVerifyRound(sma::VerifyRound(0)));
  EXPECT_TRUE(sma::IsVerifyRound(sma::VerifyRound(6)));
  EXPECT_TRUE(sma::IsVerifyRound(sma::VerifyRound(0x7fff)));
  EXPECT_FALSE(sma::IsVerifyRound(0));
  EXPECT_FALSE(sma::IsVerifyRound(0x7fff)) << "improvement rounds";
  for (uint64_t e = 1; e < 40000; ++e) {
    ASSERT_NE(sma::VerifyRound(e), sma::VerifyRound(e - 1)) << e;
    ASSERT_GE(sma::VerifyRound(e), 0x8000u) << e;
  }
  EXPECT_EQ(sma::VerifyRound(6), 0x8006u);
  // Through a wire id and back.
  const uint64_t id = sma::WireSampleId(123456, sma::VerifyRound(6));
  EXPECT_EQ(sma::VertexOfWireId(id), 123456u);
  EXPECT_EQ(sma::RoundOfWireId(id), sma::VerifyRound(6));
}

TEST(ShadeCodecVerifiedSample, PassesOnlyWhenItsChangeZErrorsBeyondIsWithinItsTolerance) {
  sma::VerifiedSample v;
  v.change = -0.25f;
  v.changeStdErr = 0.125f;
  v.tolerance = 0.625f;  // |change| + 3 sigma exactly
  EXPECT_TRUE(v.Passes());
  EXPECT_TRUE(v.Passes(3.0f));
  EXPECT_FALSE(v.Passes(3.5f));
  v.change = 0.25f;
  EXPECT_TRUE(v.Passes()) << "either sign";
  v.tolerance = 0.5f;
  EXPECT_FALSE(v.Passes());
  EXPECT_TRUE(v.Passes(2.0f));
  v.change = 0.75f;
  EXPECT_FALSE(v.Passes(0.0f)) << "the change itself beyond the tolerance";
  v = sma::VerifiedSample{};
  v.tolerance = 1.0f;
  EXPECT_TRUE(v.Passes()) << "no change, no noise";
  v.change = std::numeric_limits<float>::infinity();
  EXPECT_FALSE(v.Passes()) << "a test given up";
  v.change = std::nanf("");
  EXPECT_FALSE(v.Passes());
  v.change = 0.0f;
  v.changeStdErr = std::numeric_limits<float>::infinity();
  EXPECT_FALSE(v.Passes());
  v.changeStdErr = std::nanf("");
  EXPECT_FALSE(v.Passes());
}

}  // namespace
}  // namespace penumbra
