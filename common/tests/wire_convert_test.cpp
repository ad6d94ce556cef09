// The wire <-> domain layer (wire_convert.h): what the SMA sends a client
// arrives as it was meant, through real bytes, and a SceneInfo or
// SessionOptions that a client or SMA could not use is refused once, here,
// with a message naming what is wrong.

#include "penumbra/common/wire_convert.h"

#include <cmath>
#include <limits>
#include <string>

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
