// The client's GL code on a real OpenGL implementation (Mesa, EGL
// surfaceless: no X server needed): the tone-mapping shader against
// common/tonemap.h, and the mesh renderer against what the store holds,
// including removals, slot reuse, upload sizes and textures; and the HUD
// (Dear ImGui) in a GLFW window under a private Xvfb.

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <thread>

#include <gtest/gtest.h>

#include "gl/context.h"
#include "gl/frame_targets.h"
#include "gl/hud.h"
#include "gl/mesh_renderer.h"
#include "gl/sky_renderer.h"
#include "gl/tone_mapper.h"
#include "penumbra/client/client_model.h"
#include "penumbra/client/projection.h"
#include "penumbra/client/texture_filtering.h"
#include "penumbra/common/camera.h"
#include "penumbra/common/scene.h"
#include "support/delta_builder.h"
#include "support/fake_sma.h"
#include "support/process.h"
#include "support/xvfb.h"

namespace penumbra::client::gl {
namespace {

using testing::DeltaBuilder;

struct IgnoredRequests : SessionRequests {
  void RequestTexture(uint64_t, uint32_t texture) override { requested.push_back(texture); }
  void AbandonConnection(uint64_t, const std::string& reason) override { ADD_FAILURE() << "abandoned: " << reason; }
  std::vector<uint32_t> requested;
};

class GlTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto context = CreateSurfacelessContext();
    ASSERT_TRUE(context.ok()) << context.error().message;
    context_ = std::move(*context);
  }
  std::unique_ptr<Context> context_;
};

Rgb PixelAt(const std::vector<float>& rgb, int width, int x, int y) {
  const size_t i = (size_t(y) * size_t(width) + size_t(x)) * 3;
  return Rgb(rgb[i], rgb[i + 1], rgb[i + 2]);
}

void ExpectRgbNear(const Rgb& got, const Rgb& expected, float tolerance, const std::string& where) {
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(got[c], expected[c], tolerance) << where << " channel " << c;
}

TEST_F(GlTest, ToneMappingShaderMirrorsTheCpuCode) {
  const std::vector<Rgb> radiance = {Rgb(0.0f),          Rgb(1e-4f),           Rgb(0.01f),
                                     Rgb(0.1f),          Rgb(0.5f, 0.1f, 0.05f), Rgb(1.0f),
                                     Rgb(2.0f, 1.0f, 3.0f), Rgb(5.0f, 3.0f, 1.0f), Rgb(100.0f),
                                     Rgb(1000.0f, 900.0f, 800.0f), Rgb(0.0f, 0.0f, 0.3f), Rgb(0.02f, 0.3f, 0.01f)};
  const int width = int(radiance.size()) + 1;  // the last pixel is background
  FrameTargets targets;
  ASSERT_TRUE(targets.Resize({width, 1}).ok());
  std::vector<float> rgba;
  for (const Rgb& r : radiance) rgba.insert(rgba.end(), {r.r, r.g, r.b, 1.0f});
  rgba.insert(rgba.end(), {0.0f, 0.0f, 0.0f, 0.0f});
  glBindTexture(GL_TEXTURE_2D, targets.RadianceTexture());
  glTexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, width, 1, GL_RGBA, GL_FLOAT, rgba.data());
  auto toneMapper = ToneMapper::Create();
  ASSERT_TRUE(toneMapper.ok()) << toneMapper.error().message;

  const ViewLuminance view = MeasureLuminance(radiance);
  const DragoParams scene{0.85f, 100.0f, 1.5f};
  auto encoded = [](const std::vector<float>& linear, int i) {
    return Rgb(LinearToSrgb(linear[size_t(3 * i)]), LinearToSrgb(linear[size_t(3 * i + 1)]),
               LinearToSrgb(linear[size_t(3 * i + 2)]));
  };
  const float oneLevel = 1.01f / 255.0f;  // the display image has 8 bits per channel

  ToneSettings drago;
  drago.exposureStops = 0.5f;
  targets.BeginDisplay();
  toneMapper->Draw(targets.RadianceTexture(), view, scene, drago);
  std::vector<float> display = targets.ReadDisplay();
  DragoParams scaled = scene;
  scaled.exposure *= std::exp2(0.5f);
  for (size_t i = 0; i < radiance.size(); ++i) {
    const Rgb cpu = ToneMapDrago(radiance[i], view, scaled);
    const Rgb expected(LinearToSrgb(cpu.r), LinearToSrgb(cpu.g), LinearToSrgb(cpu.b));
    ExpectRgbNear(encoded(display, int(i)), expected, oneLevel, "Drago, pixel " + std::to_string(i));
  }
  const Rgb background(kBackgroundDisplay[0], kBackgroundDisplay[1], kBackgroundDisplay[2]);
  ExpectRgbNear(encoded(display, width - 1), background, oneLevel, "background");

  ToneSettings simple;
  simple.op = ToneOperator::kExposureGamma;
  simple.exposureStops = -1.0f;
  simple.gamma = 2.0f;
  toneMapper->Draw(targets.RadianceTexture(), view, scene, simple);
  display = targets.ReadDisplay();
  const float exposure = std::exp2(-1.0f) * 0.18f / view.logAverage;
  for (size_t i = 0; i < radiance.size(); ++i) {
    const Rgb cpu = ToneMapExposure(radiance[i], exposure);
    const Rgb expected(std::sqrt(cpu.r), std::sqrt(cpu.g), std::sqrt(cpu.b));
    ExpectRgbNear(encoded(display, int(i)), expected, oneLevel, "exposure+gamma, pixel " + std::to_string(i));
  }
}

TEST_F(GlTest, SkyShowsSkyLightRadianceAlongEachPixelsRay) {
  // A tilted camera so that pixels span ground, horizon and zenith.
  SkyLight sky;
  sky.up = Vec3(0.0f, 0.0f, 1.0f);
  sky.zenith = Rgb(0.1f, 0.3f, 1.0f);
  sky.horizon = Rgb(1.0f, 0.9f, 0.8f);
  sky.ground = Rgb(0.05f, 0.04f, 0.02f);

  CameraView view;
  view.pose = CameraPose{Vec3(3.0f, -2.0f, 1.0f), Vec3(0.0f, 0.0f, 1.6f), Vec3(0.0f, 0.0f, 1.0f)};
  view.fovYDeg = 100.0f;
  view.width = 48;
  view.height = 32;
  Bounds3 bounds;
  bounds.Extend(Vec3(-1.0f));
  bounds.Extend(Vec3(1.0f));
  auto renderer = SkyRenderer::Create();
  ASSERT_TRUE(renderer.ok()) << renderer.error().message;
  FrameTargets targets;
  ASSERT_TRUE(targets.Resize({view.width, view.height}).ok());
  targets.BeginRadiance();
  renderer->Draw(WorldToClip(view, bounds), sky);
  const std::vector<float> image = targets.ReadRadiance();

  const PinholeCamera camera(view);
  bool sawGround = false, sawZenithSide = false;
  for (int y = 0; y < view.height; y += 3) {
    for (int x = 0; x < view.width; x += 3) {
      const Vec3 direction = camera.DirectionThrough(float(x) + 0.5f, float(y) + 0.5f);
      const float c = glm::dot(direction, sky.up);
      sawGround |= c < -0.3f;
      sawZenithSide |= c > 0.3f;
      ExpectRgbNear(PixelAt(image, view.width, x, y), sky.Radiance(direction), 2e-3f,
                    "pixel " + std::to_string(x) + "," + std::to_string(y));
    }
  }
  EXPECT_TRUE(sawGround && sawZenithSide) << "the view should span the sky's range";
}

// Mesa's surfaceless EGL is llvmpipe here: isotropic filtering unless asked
// (texture_filtering.h), and what is asked within the implementation's limit.
TEST_F(GlTest, TexturesAreFilteredIsotropicallyOnASoftwareRasterizerUnlessAsked) {
  const auto* name = reinterpret_cast<const char*>(glGetString(GL_RENDERER));
  ASSERT_NE(name, nullptr);
  auto byDefault = MeshRenderer::Create();
  ASSERT_TRUE(byDefault.ok()) << byDefault.error().message;
  EXPECT_EQ(byDefault->Anisotropy(), IsSoftwareRasterizer(name) ? 1.0f : 16.0f) << name;
  auto asked = MeshRenderer::Create(4.0f);
  ASSERT_TRUE(asked.ok()) << asked.error().message;
  GLfloat limit = 1.0f;
  if (epoxy_has_gl_extension("GL_EXT_texture_filter_anisotropic")) glGetFloatv(GL_MAX_TEXTURE_MAX_ANISOTROPY_EXT, &limit);
  EXPECT_EQ(asked->Anisotropy(), std::min(4.0f, std::max(limit, 1.0f)));
}

class MeshRendererTest : public GlTest {
 protected:
  static constexpr int kSize = 64;

  void SetUp() override {
    GlTest::SetUp();
    auto renderer = MeshRenderer::Create();
    ASSERT_TRUE(renderer.ok()) << renderer.error().message;
    renderer_.emplace(std::move(*renderer));
    ASSERT_TRUE(targets_.Resize({kSize, kSize}).ok());
    Connected connected;
    connected.connection = 1;
    connected.scene = testing::UnitSquareScene(1);
    // Some tests park triangles far off screen (x up to 2100): the scene says
    // it is that large, or the store would refuse them (MeshStore::SetVertexBounds).
    connected.scene.bounds.Extend(Vec3(2101.0f, 1.0f, 0.0f));
    Apply(std::move(connected));
  }

  void Apply(SessionEvent event) {
    std::vector<SessionEvent> events;
    events.push_back(std::move(event));
    model_.Apply(std::move(events), requests_);
    const auto ok = renderer_->Sync(model_);
    ASSERT_TRUE(ok.ok()) << ok.error().message;
  }
  void ApplyDelta(const DeltaBuilder& d) { Apply(DeltaReceived{1, 1, d.Shared()}); }

  // The unit square seen from +z fills the middle of the image: pixel
  // (x, y) looks at world (x', y') with x' growing right and y' growing up.
  std::vector<float> Draw() {
    CameraView view;
    view.pose = CameraPose{Vec3(0.5f, 0.5f, 2.0f), Vec3(0.5f, 0.5f, 0.0f), Vec3(0, 1, 0)};
    view.width = view.height = kSize;
    Bounds3 bounds;
    bounds.Extend(Vec3(0, 0, 0));
    bounds.Extend(Vec3(1, 1, 0));
    targets_.BeginRadiance();
    renderer_->DrawRadiance(WorldToClip(view, bounds));
    return targets_.ReadRadiance();
  }

  std::optional<MeshRenderer> renderer_;
  FrameTargets targets_;
  ClientModel model_;
  IgnoredRequests requests_;
};

// Pixels inside the lower-right half (x' > y') and the upper-left half of the square.
constexpr int kLowerRightX = 40, kLowerRightY = 40;
constexpr int kUpperLeftX = 24, kUpperLeftY = 24;

TEST_F(MeshRendererTest, DrawsTheHeldTrianglesAndNothingInRemovedSlots) {
  const Rgb grey(0.5f, 0.25f, 0.125f);
  DeltaBuilder quad(1, 1);
  quad.Vertex(1, Vec3(0, 0, 0), grey).Vertex(2, Vec3(1, 0, 0), grey).Vertex(3, Vec3(1, 1, 0), grey);
  quad.Vertex(4, Vec3(0, 1, 0), grey);
  quad.Triangle(10, {1, 2, 3}).Triangle(11, {1, 3, 4});
  // Far off screen, so that the store is much larger than what later changes.
  for (uint64_t i = 0; i < 2000; ++i) {
    const float x = 100.0f + float(i);
    quad.Vertex(100 + 3 * i, Vec3(x, 0, 0), grey).Vertex(101 + 3 * i, Vec3(x + 0.5f, 0, 0), grey);
    quad.Vertex(102 + 3 * i, Vec3(x, 0.5f, 0), grey).Triangle(1000 + i, {100 + 3 * i, 101 + 3 * i, 102 + 3 * i});
  }
  ApplyDelta(quad);
  const size_t firstUpload = renderer_->LastUploadBytes();
  std::vector<float> image = Draw();
  ExpectRgbNear(PixelAt(image, kSize, kLowerRightX, kLowerRightY), grey, 1e-6f, "lower right");
  ExpectRgbNear(PixelAt(image, kSize, kUpperLeftX, kUpperLeftY), grey, 1e-6f, "upper left");
  ExpectRgbNear(PixelAt(image, kSize, 1, 1), Rgb(0.0f), 0.0f, "background");

  // Removing triangle 10 empties its slot on the GPU.
  ApplyDelta(DeltaBuilder(2, 1, wire::DELTA_KIND_REMOVED).Remove(10));
  image = Draw();
  ExpectRgbNear(PixelAt(image, kSize, kLowerRightX, kLowerRightY), Rgb(0.0f), 0.0f, "removed");
  ExpectRgbNear(PixelAt(image, kSize, kUpperLeftX, kUpperLeftY), grey, 1e-6f, "kept");

  // A new triangle reuses the slot; only the changed slots are uploaded.
  const Rgb blue(0.1f, 0.2f, 0.9f);
  DeltaBuilder refill(3, 1, wire::DELTA_KIND_SHADED);
  refill.Vertex(5, Vec3(0, 0, 0), blue).Vertex(6, Vec3(1, 0, 0), blue).Vertex(7, Vec3(1, 1, 0), blue);
  refill.Triangle(12, {5, 6, 7});
  ApplyDelta(refill);
  EXPECT_GT(renderer_->LastUploadBytes(), 0u);
  EXPECT_LT(renderer_->LastUploadBytes(), firstUpload / 50) << "uploads follow the change, not the store";
  image = Draw();
  ExpectRgbNear(PixelAt(image, kSize, kLowerRightX, kLowerRightY), blue, 1e-6f, "refilled");
}

TEST_F(MeshRendererTest, TexturedTrianglesShowTextureTimesIrradianceOnceItArrives) {
  // Material 1 has albedo 1 and texture 0; irradiance pi gives radiance = texture.
  const Rgb vertexRadiance(0.3f);
  const Rgb irradiance(kPi);
  DeltaBuilder d(1, 1);
  d.Vertex(1, Vec3(0, 0, 0), vertexRadiance, irradiance).Vertex(2, Vec3(1, 0, 0), vertexRadiance, irradiance);
  d.Vertex(3, Vec3(1, 1, 0), vertexRadiance, irradiance);
  d.Triangle(10, {1, 2, 3}, 1, std::array<float, 6>{0.25f, 0.25f, 0.75f, 0.25f, 0.75f, 0.75f});
  ApplyDelta(d);
  ASSERT_EQ(requests_.requested, std::vector<uint32_t>{0});
  ExpectRgbNear(PixelAt(Draw(), kSize, kLowerRightX, kLowerRightY), vertexRadiance, 1e-6f, "before the texture");

  TextureReceived texture;
  texture.connection = 1;
  texture.texture = 0;
  texture.width = 1;
  texture.height = 1;
  texture.rgb8 = std::string("\x80\x40\xff", 3);
  Apply(std::move(texture));
  const Rgb expected(SrgbToLinear(128.0f / 255.0f), SrgbToLinear(64.0f / 255.0f), 1.0f);
  ExpectRgbNear(PixelAt(Draw(), kSize, kLowerRightX, kLowerRightY), expected, 2e-3f, "textured");
}

// Issue 14: a movable object's vertices are in its space and the vertex
// shader places them with its transform; a MOVED delta moves the triangle on
// screen while uploading only the transform table (48 bytes per entry).
TEST_F(MeshRendererTest, AMovedObjectIsDrawnAtItsNewPlaceWithoutAVertexUpload) {
  Connected connected;
  connected.connection = 2;
  connected.scene = testing::UnitSquareScene(2);
  connected.scene.objects.push_back(ClientObject{"box", Bounds3{}, RigidTransform::Identity(), false});
  Apply(std::move(connected));
  const Rgb grey(0.5f, 0.25f, 0.125f);
  DeltaBuilder d(1, 1);
  d.Vertex(1, Vec3(0, 0, 0), grey).Vertex(2, Vec3(1, 0, 0), grey).Vertex(3, Vec3(1, 1, 0), grey);
  d.Triangle(10, {1, 2, 3});
  for (int i = 0; i < 3; ++i) d.Mutable().add_vertex_objects(1);
  // Many more of the object's triangles, off screen: the move's cost must not depend on them.
  for (uint64_t i = 0; i < 3000; ++i) {
    const float x = 100.0f + float(i);
    d.Vertex(100 + 3 * i, Vec3(x, 0, 0), grey).Vertex(101 + 3 * i, Vec3(x + 0.5f, 0, 0), grey);
    d.Vertex(102 + 3 * i, Vec3(x, 0.5f, 0), grey).Triangle(1000 + i, {100 + 3 * i, 101 + 3 * i, 102 + 3 * i});
    for (int c = 0; c < 3; ++c) d.Mutable().add_vertex_objects(1);
  }
  Apply(DeltaReceived{2, 1, d.Shared()});
  EXPECT_GT(renderer_->LastUploadBytes(), 9000 * sizeof(GpuVertex)) << "the first delta uploads its vertices";
  std::vector<float> image = Draw();
  ExpectRgbNear(PixelAt(image, kSize, kLowerRightX, kLowerRightY), grey, 1e-6f, "the object where it was");
  ExpectRgbNear(PixelAt(image, kSize, kUpperLeftX, kUpperLeftY), Rgb(0.0f), 0.0f, "nothing there yet");

  // Half a turn about z, then (1, 1, 0): the lower-right triangle lands on the upper-left half.
  const RigidTransform turned = RigidTransform::FromAxisAngle(Vec3(0, 0, 1), kPi, Vec3(1, 1, 0));
  DeltaBuilder moved(2, 1, wire::DELTA_KIND_MOVED);
  moved.Mutable().set_scene_epoch(1);
  moved.Mutable().add_moved_objects(1);
  for (float v : turned.ToRowMajor()) moved.Mutable().add_moved_object_transforms(v);
  Apply(DeltaReceived{2, 1, moved.Shared()});
  EXPECT_EQ(renderer_->LastUploadBytes(), 2 * sizeof(GpuObjectTransform))
      << "the table only (96 bytes), not the object's 9003 vertices (432 kB)";
  image = Draw();
  ExpectRgbNear(PixelAt(image, kSize, kLowerRightX, kLowerRightY), Rgb(0.0f), 0.0f, "moved away");
  ExpectRgbNear(PixelAt(image, kSize, kUpperLeftX, kUpperLeftY), grey, 1e-6f, "moved here");

  // A local (dragged) transform is drawn the same way, and dropping it goes back.
  model_.Mesh().SetLocalTransform(1, RigidTransform::Identity());
  ASSERT_TRUE(renderer_->Sync(model_).ok());
  ExpectRgbNear(PixelAt(Draw(), kSize, kLowerRightX, kLowerRightY), grey, 1e-6f, "dragged back");
  model_.Mesh().SetLocalTransform(1, std::nullopt);
  ASSERT_TRUE(renderer_->Sync(model_).ok());
  ExpectRgbNear(PixelAt(Draw(), kSize, kUpperLeftX, kUpperLeftY), grey, 1e-6f, "where the SMA has it");
}

// --- The HUD (Dear ImGui), in a real GLFW window under a private Xvfb ---------

class HudTest : public ::testing::Test {
 protected:
  static constexpr int kWidth = 1280, kHeight = 720;

  void SetUp() override {
    auto xvfb = testing::XvfbServer::Start(testing::MakeTempDir("penumbra-hud-test"), kWidth, kHeight);
    if (!xvfb.ok()) GTEST_SKIP() << "no Xvfb: " << xvfb.error().message;
    xvfb_.emplace(std::move(*xvfb));
    const char* display = std::getenv("DISPLAY");
    savedDisplay_ = display ? display : "";
    ::setenv("DISPLAY", xvfb_->Display().c_str(), 1);
    auto window = Window::Open(kWidth, kHeight, "hud test", /*visible=*/true);
    ASSERT_TRUE(window.ok()) << window.error().message;
    window_ = std::move(*window);
    auto hud = Hud::Create(*window_);
    ASSERT_TRUE(hud.ok()) << hud.error().message;
    hud_ = std::move(*hud);
  }
  void TearDown() override {
    hud_.reset();
    window_.reset();
    if (savedDisplay_.empty())
      ::unsetenv("DISPLAY");
    else
      ::setenv("DISPLAY", savedDisplay_.c_str(), 1);
  }

  // Draws the HUD over black a few times (ImGui sizes a new window over its
  // first frames) and reads the window back, top row first, RGB bytes.
  std::vector<uint8_t> DrawOverBlack(const HudState& state, bool help) {
    HudControls controls;
    for (int frame = 0; frame < 4; ++frame) {
      window_->PollEvents();
      glBindFramebuffer(GL_FRAMEBUFFER, 0);
      glViewport(0, 0, kWidth, kHeight);
      glClearColor(0.0f, 0.0f, 0.0f, 1.0f);
      glClear(GL_COLOR_BUFFER_BIT);
      hud_->Draw(state, controls, help);
      if (frame < 3) {
        window_->SwapBuffers();
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
      }
    }
    std::vector<uint8_t> pixels(size_t(kWidth) * kHeight * 3);
    glPixelStorei(GL_PACK_ALIGNMENT, 1);
    glReadBuffer(GL_BACK);
    glReadPixels(0, 0, kWidth, kHeight, GL_RGB, GL_UNSIGNED_BYTE, pixels.data());
    std::vector<uint8_t> topFirst(pixels.size());
    for (int y = 0; y < kHeight; ++y)
      std::copy_n(pixels.begin() + ptrdiff_t(y) * kWidth * 3, kWidth * 3,
                  topFirst.begin() + ptrdiff_t(kHeight - 1 - y) * kWidth * 3);
    return topFirst;
  }

  // Fraction of non-black pixels in [x0, x1) x [y0, y1), y from the top.
  static double Covered(const std::vector<uint8_t>& rgb, int x0, int y0, int x1, int y1) {
    size_t lit = 0, all = 0;
    for (int y = y0; y < y1; ++y)
      for (int x = x0; x < x1; ++x, ++all) {
        const size_t i = (size_t(y) * kWidth + size_t(x)) * 3;
        lit += (rgb[i] | rgb[i + 1] | rgb[i + 2]) != 0;
      }
    return double(lit) / double(all);
  }

  std::optional<testing::XvfbServer> xvfb_;
  std::string savedDisplay_;
  std::unique_ptr<Window> window_;
  std::unique_ptr<Hud> hud_;
};

HudState WaitingForARenderer() {
  HudState s;
  s.scene = "cornell-box";
  s.sma = "127.0.0.1:7200";
  s.connection = "connected";
  s.connected = true;
  s.progress.renderersConnected = 0;
  s.progress.stage1Total = 5000;
  s.pendingSamples = 5000;
  s.triangles = 120;
  s.vertices = 80;
  s.walkSpeed = 0.5f;
  return s;
}

// The panel sits in the top-left corner, compact; the top centre -- where a
// ceiling light is in the default view of a room such as the Cornell box --
// stays clear, and so does everything right of the panel.
TEST_F(HudTest, ThePanelKeepsToTheTopLeftCornerAndOffTheTopCentre) {
  const auto rgb = DrawOverBlack(WaitingForARenderer(), /*help=*/false);
  EXPECT_GT(Covered(rgb, 12, 12, 300, 60), 0.5) << "the panel is in the top-left corner";
  EXPECT_EQ(Covered(rgb, kWidth * 2 / 5, 0, kWidth * 3 / 5, kHeight * 2 / 5), 0.0) << "the top centre is clear";
  EXPECT_EQ(Covered(rgb, 440, 0, kWidth, kHeight), 0.0) << "nothing right of the panel";
  EXPECT_EQ(Covered(rgb, 0, kHeight / 2, kWidth, kHeight), 0.0) << "the panel is compact: the lower half is clear";
}

TEST_F(HudTest, TheHelpOverlayIsDrawnInTheMiddleOnlyWhenAskedFor) {
  const HudState state = WaitingForARenderer();
  const auto without = DrawOverBlack(state, /*help=*/false);
  EXPECT_EQ(Covered(without, kWidth / 2 - 100, kHeight / 2 - 50, kWidth / 2 + 100, kHeight / 2 + 50), 0.0);
  const auto with = DrawOverBlack(state, /*help=*/true);
  EXPECT_GT(Covered(with, kWidth / 2 - 100, kHeight / 2 - 50, kWidth / 2 + 100, kHeight / 2 + 50), 0.5);
}

}  // namespace
}  // namespace penumbra::client::gl
