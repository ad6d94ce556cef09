// The wire <-> domain layer (wire_convert.h): what the SMA sends a client
// arrives as it was meant, through real bytes, and a SceneInfo or
// SessionOptions that a client or SMA could not use is refused once, here,
// with a message naming what is wrong.

#include "penumbra/common/wire_convert.h"

#include <cmath>
#include <limits>
#include <string>

#include <fmt/format.h>
#include <glm/trigonometric.hpp>
#include <gtest/gtest.h>

namespace penumbra {
namespace {

void Set(wire::Vec3* v, float x, float y, float z) {
  v->set_x(x);
  v->set_y(y);
  v->set_z(z);
}

// Through bytes, as it travels.
template <typename Message>
Message ThroughBytes(const Message& in) {
  std::string bytes;
  EXPECT_TRUE(in.SerializeToString(&bytes));
  Message out;
  EXPECT_TRUE(out.ParseFromString(bytes));
  return out;
}

// A finalized two-triangle scene with a textured material, two presets and a sky.
Scene TexturedScene() {
  SceneBuilder builder;
  Material grey;
  grey.albedo = Rgb(0.5f);
  Material lamp;
  lamp.albedo = Rgb(0.1f, 0.2f, 0.3f);
  lamp.emission = Rgb(4.0f, 3.0f, 2.0f);
  Texture texture;
  texture.width = texture.height = 1;
  texture.texels = {Rgb(1.0f)};
  lamp.albedoTexture = builder.AddTexture(texture);
  const uint32_t g = builder.AddMaterial(grey);
  const uint32_t l = builder.AddMaterial(lamp);
  builder.AddQuad(Vec3(0.0f), Vec3(1, 0, 0), Vec3(0, 1, 0), g);
  builder.AddTriangle({Vec3(0, 0, 1), Vec3(1, 0, 1), Vec3(0, 1, 1)}, l);
  Scene scene;
  scene.name = "two-parts";
  scene.cameras.push_back(CameraPreset{"front", CameraPose{Vec3(0.5f, 0.5f, 3), Vec3(0.5f, 0.5f, 0), Vec3(0, 1, 0)}, 45});
  scene.cameras.push_back(CameraPreset{"side", CameraPose{Vec3(3, 0.5f, 0.5f), Vec3(0.5f), Vec3(0, 1, 0)}, 60});
  scene.sky = SkyLight{Vec3(0, 0, 1), Rgb(0.2f, 0.4f, 1.0f), Rgb(1.0f), Rgb(0.1f)};
  EXPECT_TRUE(builder.BuildInto(scene).ok());
  return scene;
}

wire::SceneInfo ValidInfo() {
  wire::SceneInfo info;
  ToWire(MakeClientScene(TexturedScene(), DragoParams{}), &info);
  return info;
}

std::string Refusal(const wire::SceneInfo& info) {
  auto scene = ClientSceneFromWire(info, 1);
  return scene ? std::string("accepted") : scene.error().message;
}

TEST(WireConvertTest, ASceneArrivesAsTheSmaMadeIt) {
  const Scene scene = TexturedScene();
  const DragoParams toneMapping{0.7f, 250.0f, 1.5f};
  const ClientScene sent = MakeClientScene(scene, toneMapping);
  ASSERT_EQ(sent.materials.size(), 2u);
  EXPECT_EQ(sent.materials[1].texture, 0);
  EXPECT_EQ(sent.textureCount, 1u);
  EXPECT_EQ(sent.identity, scene.identity);

  wire::SceneInfo info;
  ToWire(sent, &info);
  auto received = ClientSceneFromWire(ThroughBytes(info), scene.identity);
  ASSERT_TRUE(received.ok()) << received.error().message;
  EXPECT_EQ(received->name, "two-parts");
  EXPECT_EQ(received->identity, scene.identity);
  EXPECT_EQ(received->bounds.min, scene.bounds.min);
  EXPECT_EQ(received->bounds.max, scene.bounds.max);
  ASSERT_EQ(received->cameras.size(), 2u);
  EXPECT_EQ(received->cameras[1].name, "side");
  EXPECT_EQ(received->cameras[1].pose.eye, Vec3(3, 0.5f, 0.5f));
  EXPECT_EQ(received->cameras[1].fovYDeg, 60.0f);
  EXPECT_EQ(received->FindCamera("side"), 1);
  EXPECT_EQ(received->FindCamera("top"), -1);
  EXPECT_EQ(received->materials, sent.materials);
  EXPECT_EQ(received->MaterialTextures(), (std::vector<int32_t>{-1, 0}));
  EXPECT_EQ(received->textureCount, 1u);
  ASSERT_TRUE(received->sky.has_value());
  EXPECT_EQ(received->sky->up, Vec3(0, 0, 1));
  EXPECT_EQ(received->sky->zenith, Rgb(0.2f, 0.4f, 1.0f));
  EXPECT_EQ(received->sky->ground, Rgb(0.1f));
  EXPECT_EQ(received->toneMapping.bias, 0.7f);
  EXPECT_EQ(received->toneMapping.maxDisplayLuminance, 250.0f);
  EXPECT_EQ(received->toneMapping.exposure, 1.5f);

  // No sky stays no sky (the client then draws black).
  Scene noSky = scene;
  noSky.sky.reset();
  wire::SceneInfo infoNoSky;
  ToWire(MakeClientScene(noSky, toneMapping), &infoNoSky);
  EXPECT_FALSE(infoNoSky.has_sky());
  EXPECT_FALSE(ClientSceneFromWire(ThroughBytes(infoNoSky), 1)->sky.has_value());
}

TEST(WireConvertTest, ASceneInfoThatCannotBeDrawnIsRefusedWithItsReason) {
  ASSERT_EQ(Refusal(ValidInfo()), "accepted");
  const float nan = std::nanf("");

  // A count that would allocate without bound: a group per texture.
  wire::SceneInfo manyTextures = ValidInfo();
  manyTextures.set_texture_count(std::numeric_limits<uint32_t>::max());
  EXPECT_EQ(Refusal(manyTextures), "scene_info: 4294967295 textures; at most 65536 are supported");

  wire::SceneInfo missingTexture = ValidInfo();
  missingTexture.mutable_materials(1)->set_texture(1);
  EXPECT_EQ(Refusal(missingTexture), "scene_info: material 1 uses texture 1 of 1");
  missingTexture.mutable_materials(1)->set_texture(-2);
  EXPECT_EQ(Refusal(missingTexture), "scene_info: material 1 uses texture -2 of 1");

  wire::SceneInfo badColour = ValidInfo();
  Set(badColour.mutable_materials(0)->mutable_emission(), nan, 0, 0);
  EXPECT_EQ(Refusal(badColour), "scene_info: material 0 has a colour that is not finite");

  wire::SceneInfo badBounds = ValidInfo();
  Set(badBounds.mutable_bounds_max(), std::numeric_limits<float>::infinity(), 0, 0);
  EXPECT_EQ(Refusal(badBounds), "scene_info: bounds are not finite");

  wire::SceneInfo badCamera = ValidInfo();
  badCamera.mutable_cameras(1)->set_fov_y_deg(nan);
  EXPECT_EQ(Refusal(badCamera), "scene_info: camera 1 ('side') is not finite");

  wire::SceneInfo skyNotUnit = ValidInfo();
  Set(skyNotUnit.mutable_sky()->mutable_up(), 0, 0, 2);
  EXPECT_EQ(Refusal(skyNotUnit), "scene_info: sky up (0, 0, 2) is not a unit vector");
  wire::SceneInfo skyNegative = ValidInfo();
  Set(skyNegative.mutable_sky()->mutable_ground(), -1, 0, 0);
  EXPECT_EQ(Refusal(skyNegative), "scene_info: sky radiance must be finite and non-negative");
  wire::SceneInfo skyNan = ValidInfo();
  Set(skyNan.mutable_sky()->mutable_zenith(), nan, 0, 0);
  EXPECT_EQ(Refusal(skyNan), "scene_info: sky radiance must be finite and non-negative");

  for (float bias : {0.0f, 1.0f, nan}) {
    wire::SceneInfo badBias = ValidInfo();
    badBias.mutable_tone_mapping()->set_bias(bias);
    EXPECT_EQ(Refusal(badBias).rfind("scene_info: tone mapping bias", 0), 0u) << Refusal(badBias);
  }
  wire::SceneInfo badExposure = ValidInfo();
  badExposure.mutable_tone_mapping()->set_exposure(std::numeric_limits<float>::infinity());
  EXPECT_NE(Refusal(badExposure).find("exposure inf"), std::string::npos) << Refusal(badExposure);

  // An empty message (what a foreign peer's bytes often decode to) has no
  // usable tone mapping.
  EXPECT_NE(Refusal(wire::SceneInfo()).find("tone mapping"), std::string::npos);
}

// A static floor with two movable objects: a box lifted above it and an
// animated panel (issue 14).
Scene SceneWithObjects() {
  SceneBuilder builder;
  Material grey;
  grey.albedo = Rgb(0.5f);
  Material lamp;
  lamp.emission = Rgb(1.0f);
  const uint32_t g = builder.AddMaterial(grey);
  const uint32_t l = builder.AddMaterial(lamp);
  builder.AddQuad(Vec3(-2, 0, -2), Vec3(4, 0, 0), Vec3(0, 0, 4), g);
  builder.AddQuad(Vec3(-0.5f, 3, -0.5f), Vec3(1, 0, 0), Vec3(0, 0, 1), l);
  MovableObject box;
  box.name = "box";
  box.objectToWorld = RigidTransform::FromAxisAngle(Vec3(0, 1, 0), glm::radians(30.0f), Vec3(0.5f, 1.0f, 0.0f));
  builder.BeginObject(box);
  builder.AddQuad(Vec3(-0.25f, 0, -0.25f), Vec3(0.5f, 0, 0), Vec3(0, 0.5f, 0), g);
  MovableObject panel;
  panel.name = "swinging panel";
  ObjectAnimation swing;
  swing.keys = {ObjectKeyframe{0.0f, RigidTransform::Identity()},
                ObjectKeyframe{2.0f, RigidTransform::FromAxisAngle(Vec3(0, 0, 1), 0.5f, Vec3(0, 0.5f, 0))}};
  panel.animation = swing;
  builder.BeginObject(panel);
  builder.AddQuad(Vec3(1, 0, 1), Vec3(0.2f, 0, 0), Vec3(0, 0.4f, 0), g);
  builder.EndObject();
  Scene scene;
  scene.name = "objects";
  EXPECT_TRUE(builder.BuildInto(scene).ok());
  return scene;
}

wire::SceneInfo InfoWithObjects() {
  wire::SceneInfo info;
  ToWire(MakeClientScene(SceneWithObjects(), DragoParams{}), &info);
  return info;
}

TEST(WireConvertTest, MovableObjectsArriveWithTheirIdsBoundsAndPlaces) {
  const Scene scene = SceneWithObjects();
  ASSERT_EQ(scene.objects.size(), 2u);
  ScenePose pose = ScenePose::Initial(scene);
  pose.epoch = 7;
  pose.objectToWorld[0] = RigidTransform::FromAxisAngle(Vec3(1, 0, 0), 0.25f, Vec3(1, 2, 3));
  const ClientScene sent = MakeClientScene(scene, DragoParams{}, pose);
  ASSERT_EQ(sent.objects.size(), 2u);
  EXPECT_EQ(sent.sceneEpoch, 7u);

  wire::SceneInfo info;
  ToWire(sent, &info);
  ASSERT_EQ(info.objects_size(), 2);
  EXPECT_EQ(info.objects(0).object(), 1u);  // id = index + 1; 0 is the static part
  EXPECT_EQ(info.objects(1).object(), 2u);
  EXPECT_EQ(info.objects(0).object_to_world_size(), 12);
  auto received = ClientSceneFromWire(ThroughBytes(info), scene.identity);
  ASSERT_TRUE(received.ok()) << received.error().message;
  ASSERT_EQ(received->objects.size(), 2u);
  EXPECT_EQ(received->sceneEpoch, 7u);
  EXPECT_EQ(received->objects[0].name, "box");
  EXPECT_FALSE(received->objects[0].animated);
  EXPECT_EQ(received->objects[1].name, "swinging panel");
  EXPECT_TRUE(received->objects[1].animated);
  EXPECT_EQ(received->objects[0].objectBounds.min, scene.objects[0].objectBounds.min);
  EXPECT_EQ(received->objects[0].objectBounds.max, scene.objects[0].objectBounds.max);
  EXPECT_EQ(received->FindObject("box"), 1u);
  EXPECT_EQ(received->FindObject("swinging panel"), 2u);
  EXPECT_EQ(received->FindObject("chair"), 0u);
  // The pose's transform, not the scene's initial one, within the rounding
  // of re-orthonormalisation.
  const Vec3 p(0.1f, 0.2f, 0.3f);
  const Vec3 expected = pose.objectToWorld[0].ApplyPoint(p);
  const Vec3 got = received->objects[0].objectToWorld.ApplyPoint(p);
  EXPECT_NEAR(got.x, expected.x, 1e-5f);
  EXPECT_NEAR(got.y, expected.y, 1e-5f);
  EXPECT_NEAR(got.z, expected.z, 1e-5f);
  // World bounds enclose the object where it is.
  const Bounds3 world = received->objects[0].WorldBounds();
  const Vec3 corner = pose.objectToWorld[0].ApplyPoint(scene.objects[0].objectBounds.max);
  EXPECT_LE(world.min.x, corner.x + 1e-5f);
  EXPECT_GE(world.max.x, corner.x - 1e-5f);

  // Without a pose: the initial places, epoch 0; a static scene has no objects.
  EXPECT_EQ(MakeClientScene(scene, DragoParams{}).sceneEpoch, 0u);
  EXPECT_EQ(MakeClientScene(scene, DragoParams{}).objects[0].objectToWorld, scene.objects[0].objectToWorld);
  EXPECT_TRUE(ClientSceneFromWire(ValidInfo(), 1)->objects.empty());
}

TEST(WireConvertTest, AMovableObjectThatCannotBePlacedIsRefusedWithItsReason) {
  ASSERT_EQ(Refusal(InfoWithObjects()), "accepted");
  const float nan = std::nanf("");

  wire::SceneInfo outOfOrder = InfoWithObjects();
  outOfOrder.mutable_objects(1)->set_object(5);
  EXPECT_EQ(Refusal(outOfOrder),
            "scene_info: movable object 1 ('swinging panel') has id 5; ids are 1, 2, ... in order");
  wire::SceneInfo zeroId = InfoWithObjects();
  zeroId.mutable_objects(0)->set_object(0);
  EXPECT_EQ(Refusal(zeroId), "scene_info: movable object 0 ('box') has id 0; ids are 1, 2, ... in order");

  wire::SceneInfo nanBounds = InfoWithObjects();
  Set(nanBounds.mutable_objects(0)->mutable_bounds_min(), nan, 0, 0);
  EXPECT_EQ(Refusal(nanBounds), "scene_info: movable object 1 ('box') has bounds that are not finite");
  wire::SceneInfo inverted = InfoWithObjects();
  Set(inverted.mutable_objects(0)->mutable_bounds_min(), 5, 5, 5);
  EXPECT_EQ(Refusal(inverted), "scene_info: movable object 1 ('box') has bounds with min above max");

  wire::SceneInfo shortTransform = InfoWithObjects();
  shortTransform.mutable_objects(0)->mutable_object_to_world()->RemoveLast();
  EXPECT_EQ(Refusal(shortTransform),
            "scene_info: movable object 1 ('box'): a transform has 12 numbers (3x4, row-major), not 11");
  wire::SceneInfo nanTransform = InfoWithObjects();
  nanTransform.mutable_objects(1)->set_object_to_world(3, nan);
  EXPECT_EQ(Refusal(nanTransform), "scene_info: movable object 2 ('swinging panel'): transform entry 3 is not finite");
  wire::SceneInfo scaled = InfoWithObjects();
  for (int i : {0, 5, 10}) scaled.mutable_objects(0)->set_object_to_world(i, 2.0f);  // not a rotation
  EXPECT_NE(Refusal(scaled).find("scene_info: movable object 1 ('box'): the 3x3 part is not a rotation"),
            std::string::npos)
      << Refusal(scaled);
  wire::SceneInfo mirrored = InfoWithObjects();
  for (int i : {0, 1, 2}) mirrored.mutable_objects(0)->set_object_to_world(i, -mirrored.objects(0).object_to_world(i));
  EXPECT_NE(Refusal(mirrored).find("not a rotation"), std::string::npos) << Refusal(mirrored);

  // A count that would allocate without bound: a transform per object.
  wire::SceneInfo tooMany = InfoWithObjects();
  const wire::MovableObjectInfo first = tooMany.objects(0);
  for (uint32_t i = 2; i <= kMaxClientSceneObjects; ++i) {
    auto* o = i == 2 ? tooMany.mutable_objects(1) : tooMany.add_objects();
    *o = first;
    o->set_object(i);
  }
  EXPECT_EQ(Refusal(tooMany), "accepted");  // exactly the limit
  *tooMany.add_objects() = first;
  EXPECT_EQ(Refusal(tooMany), fmt::format("scene_info: {} movable objects; at most {} are supported",
                                          kMaxClientSceneObjects + 1, kMaxClientSceneObjects));
}

TEST(WireConvertTest, ToneMappingIsOneTypeOnBothSides) {
  const DragoParams params{0.8f, 120.0f, 2.0f};
  wire::ToneMapping tm;
  ToWire(params, &tm);
  auto back = ToneMappingFromWire(ThroughBytes(tm));
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_EQ(back->bias, 0.8f);
  EXPECT_EQ(back->maxDisplayLuminance, 120.0f);
  EXPECT_EQ(back->exposure, 2.0f);
  tm.set_max_display_luminance(-1.0f);
  EXPECT_FALSE(ToneMappingFromWire(tm).ok());
}

TEST(WireConvertTest, CriterionNamesComeFromOneTable) {
  ASSERT_EQ(Criteria().size(), 5u);
  EXPECT_EQ(Criteria().front().criterion, RefinementParams().criterion);  // the default first
  EXPECT_EQ(Criteria().back().criterion, Criterion::kNone);
  for (const CriterionEntry& entry : Criteria()) {
    auto parsed = ParseCriterion(entry.name);
    ASSERT_TRUE(parsed.ok()) << entry.name;
    EXPECT_EQ(*parsed, entry.criterion);
    EXPECT_EQ(CriterionName(entry.criterion), entry.name);
    EXPECT_FALSE(entry.meaning.empty());
  }
  EXPECT_EQ(CriterionNameList(), "nld_os, nld_is, rnd, nld_os_rnd or none");
  auto unknown = ParseCriterion("nld");
  ASSERT_FALSE(unknown.ok());
  EXPECT_EQ(unknown.error().message, "unknown criterion 'nld' (nld_os, nld_is, rnd, nld_os_rnd or none)");
}

TEST(WireConvertTest, SessionOptionsCarryOnlyWhatTheClientSets) {
  RefinementRequest request;
  request.criterion = Criterion::kNldIs;
  request.sReq = 0.1f;
  request.batch = 128;
  request.maxDepth = 9;
  request.noiseZ = 0.0f;
  wire::SessionOptions options;
  ToWire(request, &options);
  const wire::SessionOptions sent = ThroughBytes(options);
  EXPECT_EQ(sent.criterion(), "nld_is");
  EXPECT_FALSE(sent.has_min_pixels());
  EXPECT_FALSE(sent.has_pixel_fraction());
  auto back = RefinementRequestFromWire(sent);
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_EQ(back->criterion, Criterion::kNldIs);
  EXPECT_EQ(back->sReq, 0.1f);
  EXPECT_EQ(back->batch, 128u);
  EXPECT_EQ(back->maxDepth, 9u);
  EXPECT_EQ(back->noiseZ, 0.0f);
  EXPECT_FALSE(back->minPixels || back->largeFraction || back->aspectThreshold || back->pixelFraction);

  // An empty request keeps everything; "" as criterion keeps it.
  wire::SessionOptions none;
  ToWire(RefinementRequest{}, &none);
  EXPECT_EQ(none.criterion(), "");
  EXPECT_TRUE(RefinementRequestFromWire(none)->Empty());
}

TEST(WireConvertTest, SessionOptionsChangeOnlyWhatIsSetAndOutOfRangeIsRefused) {
  RefinementParams current;
  current.batch = 32;
  wire::SessionOptions o;
  o.set_s_req(0.1f);
  o.set_criterion("rnd");
  auto applied = ApplySessionOptions(current, o);
  ASSERT_TRUE(applied.ok()) << applied.error().message;
  EXPECT_FLOAT_EQ(applied->sReq, 0.1f);
  EXPECT_EQ(applied->criterion, Criterion::kRnd);
  EXPECT_EQ(applied->batch, 32u);
  EXPECT_EQ(applied->minPixels, current.minPixels);

  auto refusal = [&](const wire::SessionOptions& options) {
    auto result = ApplySessionOptions(current, options);
    return result ? std::string("accepted") : result.error().message;
  };
  wire::SessionOptions deep;
  deep.set_max_depth(21);
  EXPECT_EQ(refusal(deep), "session options: max_depth = 21 is out of range");
  // 300 would wrap to 44 in eight bits: refused before it narrows.
  deep.set_max_depth(300);
  EXPECT_EQ(refusal(deep), "session options: max_depth = 300 is out of range");
  deep.set_max_depth(0);
  EXPECT_EQ(refusal(deep), "session options: max_depth = 0 is out of range");

  wire::SessionOptions nan;
  nan.set_s_req(std::nanf(""));
  EXPECT_EQ(refusal(nan), "session options: s_req = nan is out of range");
  wire::SessionOptions noBatch;
  noBatch.set_batch(0);
  EXPECT_EQ(refusal(noBatch), "session options: batch (R) = 0 is out of range");
  wire::SessionOptions noisy;
  noisy.set_noise_z(11.0f);
  EXPECT_EQ(refusal(noisy), "session options: noise_z = 11 is out of range");

  wire::SessionOptions unknown;
  unknown.set_criterion("nld_xx");
  EXPECT_EQ(refusal(unknown), "unknown criterion 'nld_xx' (nld_os, nld_is, rnd, nld_os_rnd or none)");
  // Refused changes nothing: the caller keeps `current`.
  EXPECT_EQ(current.batch, 32u);
}

}  // namespace
}  // namespace penumbra
