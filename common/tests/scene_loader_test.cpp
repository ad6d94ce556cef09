// LoadScene on mesh files (OBJ/MTL quirks, textures, glTF), scene files
// (.json), the repository's scenes and the shared real-world scenes, and on
// bad input of every kind.

#include <algorithm>
#include <array>
#include <cmath>
#include <fstream>
#include <functional>
#include <iterator>
#include <limits>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "penumbra/common/image_io.h"
#include "penumbra/common/scene.h"
#include "test_files.h"

namespace penumbra {
namespace {

namespace fs = std::filesystem;
using testing::CornellBoxObj;
using testing::ExpectNear;
using testing::kLinearOfSrgb128;
using testing::ScratchDir;
using testing::SharedScene;
using testing::SourceDir;
using testing::TestData;


const Material* FindMaterial(const Scene& scene, std::string_view name) {
  for (const Material& m : scene.materials)
    if (m.name == name) return &m;
  return nullptr;
}

std::vector<uint32_t> TrianglesOf(const Scene& scene, std::string_view materialName) {
  std::vector<uint32_t> out;
  for (uint32_t t = 0; t < scene.triangles.size(); ++t)
    if (scene.MaterialOf(t).name == materialName) out.push_back(t);
  return out;
}

// (b1, b2) of `point` on triangle `t` (see Scene::PointAt), if it lies inside.
std::optional<std::array<float, 2>> Barycentrics(const Scene& scene, uint32_t t, const Vec3& point) {
  const Vec3 e1 = scene.Position(t, 1) - scene.Position(t, 0);
  const Vec3 e2 = scene.Position(t, 2) - scene.Position(t, 0);
  const Vec3 d = point - scene.Position(t, 0);
  const float d11 = glm::dot(e1, e1), d12 = glm::dot(e1, e2), d22 = glm::dot(e2, e2);
  const float denom = d11 * d22 - d12 * d12;
  const float b1 = (d22 * glm::dot(d, e1) - d12 * glm::dot(d, e2)) / denom;
  const float b2 = (d11 * glm::dot(d, e2) - d12 * glm::dot(d, e1)) / denom;
  if (b1 < 0.0f || b2 < 0.0f || b1 + b2 > 1.0f) return std::nullopt;
  return std::array<float, 2>{b1, b2};
}

std::string ReadFile(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

// Brute-force ray casting over all triangles (Moller-Trumbore): slow but
// independent of the renderer, enough for the few hundred rays these tests
// cast to check where sunlight lands.
class RayCaster {
 public:
  struct Hit {
    float distance;
    uint32_t triangle;
  };

  explicit RayCaster(const Scene& scene) {
    triangles_.reserve(scene.triangles.size());
    for (uint32_t t = 0; t < scene.triangles.size(); ++t) {
      const Vec3& p0 = scene.Position(t, 0);
      triangles_.push_back({p0, scene.Position(t, 1) - p0, scene.Position(t, 2) - p0});
    }
  }

  std::optional<Hit> Intersect(const Vec3& origin, const Vec3& direction,
                               float maxDistance = std::numeric_limits<float>::infinity()) const {
    std::optional<Hit> closest;
    float best = maxDistance;
    for (uint32_t i = 0; i < triangles_.size(); ++i) {
      const Tri& tri = triangles_[i];
      const Vec3 p = glm::cross(direction, tri.e2);
      const float det = glm::dot(tri.e1, p);
      if (std::abs(det) < 1e-12f) continue;
      const float inv = 1.0f / det;
      const Vec3 s = origin - tri.p0;
      const float u = glm::dot(s, p) * inv;
      if (u < 0.0f || u > 1.0f) continue;
      const Vec3 q = glm::cross(s, tri.e1);
      const float v = glm::dot(direction, q) * inv;
      if (v < 0.0f || u + v > 1.0f) continue;
      const float t = glm::dot(tri.e2, q) * inv;
      if (t > 1e-4f && t < best) {
        best = t;
        closest = Hit{t, i};
      }
    }
    return closest;
  }

  bool Occluded(const Vec3& origin, const Vec3& direction,
                float maxDistance = std::numeric_limits<float>::infinity()) const {
    return Intersect(origin, direction, maxDistance).has_value();
  }

 private:
  struct Tri {
    Vec3 p0, e1, e2;
  };
  std::vector<Tri> triangles_;
};

// Whether the sun's centre is visible from a surface point, nudged off the
// surface toward the side the ray came from.
bool SunVisible(const Scene& scene, const RayCaster& caster, const Vec3& rayDirection, const Vec3& point,
                uint32_t triangle) {
  Vec3 n = scene.GeometricNormal(triangle);
  if (glm::dot(n, rayDirection) > 0.0f) n = -n;
  return glm::dot(n, scene.sun->directionToSun) > 0.0f &&
         !caster.Occluded(point + 1e-3f * n, scene.sun->directionToSun);
}

// Fraction of a camera's pixels (on a coarse grid) that see a sunlit surface
// of material `materialName`.
double SunlitFraction(const Scene& scene, const RayCaster& caster, const CameraPreset& preset,
                      std::string_view materialName, int width, int height) {
  CameraView view;
  view.pose = preset.pose;
  view.fovYDeg = preset.fovYDeg;
  view.width = width;
  view.height = height;
  const PinholeCamera camera(view);
  int sunlit = 0;
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      const Vec3 d = camera.DirectionThrough(float(x) + 0.5f, float(y) + 0.5f);
      const auto hit = caster.Intersect(camera.Origin(), d);
      if (hit && scene.MaterialOf(hit->triangle).name == materialName &&
          SunVisible(scene, caster, d, camera.Origin() + hit->distance * d, hit->triangle))
        ++sunlit;
    }
  }
  return double(sunlit) / double(width * height);
}

// Every straight segment between consecutive keyframe eyes is free of
// geometry: the walkthrough does not pass through walls.
void ExpectPathIsClear(const Scene& scene, const RayCaster& caster, const CameraPath& path) {
  for (size_t i = 1; i < path.keyframes.size(); ++i) {
    const Vec3 from = path.keyframes[i - 1].pose.eye;
    const Vec3 to = path.keyframes[i].pose.eye;
    const float length = glm::length(to - from);
    if (length == 0.0f) continue;
    const auto hit = caster.Intersect(from, (to - from) / length, length);
    EXPECT_FALSE(hit.has_value()) << "path '" << path.name << "' between keyframes " << i - 1 << " and " << i
                                  << " passes through material '" << scene.MaterialOf(hit->triangle).name << "'";
  }
}

// --- The repository's Cornell box: OBJ quirks, crease splitting -----------


TEST(SceneLoaderTest, CornellBoxObjWithCrlfTabsAndNegativeIndicesLoads) {
  auto scene = LoadScene(CornellBoxObj());
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  // 18 quads (SOURCE.md); none is degenerate, but each box lists one of its
  // faces twice (its "bottom" face repeats a side face): 2 quads dropped.
  EXPECT_EQ(scene->triangles.size(), 32u);
  EXPECT_EQ(scene->name, "CornellBox-Original");
  // The mtllib line ends in \r: all 8 named materials were found, with their Kd.
  EXPECT_EQ(scene->materials.size(), 8u);
  ASSERT_NE(FindMaterial(*scene, "rightWall"), nullptr);
  ExpectNear(FindMaterial(*scene, "rightWall")->albedo, Vec3(0.14f, 0.45f, 0.091f), 1e-6f);
  EXPECT_TRUE(scene->textures.empty());
  EXPECT_FALSE(scene->sun.has_value());
  EXPECT_FALSE(scene->sky.has_value());

  ASSERT_EQ(scene->emissiveTriangles.size(), 2u);
  for (uint32_t t : scene->emissiveTriangles) {
    EXPECT_EQ(scene->MaterialOf(t).name, "light");
    ExpectNear(scene->MaterialOf(t).emission, Vec3(17, 12, 4), 0.0f);
    ExpectNear(scene->GeometricNormal(t), Vec3(0, -1, 0), 1e-6f, "the light faces down");
  }
  ExpectNear(scene->bounds.min, Vec3(-1.02f, 0.0f, -1.04f), 1e-6f);
  ExpectNear(scene->bounds.max, Vec3(1.00f, 1.99f, 0.99f), 1e-6f);
}

TEST(SceneLoaderTest, CornellBoxVerticesAreNotSharedAcrossItsRightAngles) {
  auto scene = LoadScene(CornellBoxObj());
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  // Every face of the box meets its neighbours at about 90 degrees, so every
  // vertex must belong to one flat side only.
  std::vector<std::vector<uint32_t>> trianglesAt(scene->vertices.size());
  for (uint32_t t = 0; t < scene->triangles.size(); ++t)
    for (uint32_t v : scene->triangles[t].v) trianglesAt[v].push_back(t);
  for (uint32_t v = 0; v < scene->vertices.size(); ++v) {
    ASSERT_FALSE(trianglesAt[v].empty());
    for (uint32_t t : trianglesAt[v])
      EXPECT_GT(glm::dot(scene->vertices[v].normal, scene->GeometricNormal(t)), 0.99f)
          << "vertex " << v << " is shared by triangles facing apart";
  }
  // Corners shared by 3 faces became 3 vertices: more vertices than positions.
  std::vector<Vec3> positions;
  for (const Vertex& v : scene->vertices)
    if (std::find(positions.begin(), positions.end(), v.position) == positions.end()) positions.push_back(v.position);
  EXPECT_GT(scene->vertices.size(), positions.size());

  // A crease angle above 90 degrees merges the box's corners again.
  SceneLoadOptions smooth;
  smooth.creaseAngleDeg = 100.0f;
  auto merged = LoadScene(CornellBoxObj(), smooth);
  ASSERT_TRUE(merged.ok()) << merged.error().message;
  EXPECT_LT(merged->vertices.size(), scene->vertices.size());
}

TEST(SceneLoaderTest, MeshFileWithoutCamerasGetsADefaultViewOfTheWholeScene) {
  auto scene = LoadScene(CornellBoxObj());
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  ASSERT_EQ(scene->cameras.size(), 1u);
  const CameraPreset& camera = scene->cameras[0];
  EXPECT_EQ(camera.name, "default");
  CameraView view;
  view.pose = camera.pose;
  view.fovYDeg = camera.fovYDeg;
  ASSERT_TRUE(ValidateCameraView(view).ok());
  // Every corner of the bounds lies inside the vertical field of view cone.
  const Vec3 forward = glm::normalize(camera.pose.target - camera.pose.eye);
  const float cosHalfFov = std::cos(0.5f * camera.fovYDeg * kPi / 180.0f);
  for (int corner = 0; corner < 8; ++corner) {
    const Vec3 p((corner & 1) ? scene->bounds.max.x : scene->bounds.min.x,
                 (corner & 2) ? scene->bounds.max.y : scene->bounds.min.y,
                 (corner & 4) ? scene->bounds.max.z : scene->bounds.min.z);
    EXPECT_GE(glm::dot(glm::normalize(p - camera.pose.eye), forward), cosHalfFov) << "corner " << corner;
  }
}

// --- Textures --------------------------------------------------------------

TEST(SceneLoaderTest, ObjTextureIsDecodedFromSrgbOnceAndSampledRightSideUp) {
  auto scene = LoadScene(TestData("textured_quads.obj"));
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  // Both materials use checker_2x2.png; it is decoded once.
  ASSERT_EQ(scene->textures.size(), 1u);
  const Material* tinted = FindMaterial(*scene, "tinted");
  const Material* plain = FindMaterial(*scene, "plain");
  ASSERT_TRUE(tinted && plain);
  EXPECT_EQ(tinted->albedoTexture, 0);
  EXPECT_EQ(plain->albedoTexture, 0);
  ExpectNear(tinted->albedo, Vec3(0.5f, 1.0f, 1.0f), 0.0f);

  const Texture& texture = scene->textures[0];
  ASSERT_EQ(texture.width, 2);
  ASSERT_EQ(texture.height, 2);
  // Row 0 is the image's top row: red, green; then blue, and grey 128 decoded to linear.
  ExpectNear(texture.texels[0], Vec3(1, 0, 0), 1e-6f, "top-left");
  ExpectNear(texture.texels[2], Vec3(0, 0, 1), 1e-6f, "bottom-left");
  ExpectNear(texture.texels[3], Vec3(kLinearOfSrgb128), 1e-6f, "bottom-right");
  // v = 1 is the top of the image: texel centres at u, v = 0.25 / 0.75.
  ExpectNear(texture.Sample(Vec2(0.25f, 0.75f)), Vec3(1, 0, 0), 1e-6f, "top-left by uv");
  ExpectNear(texture.Sample(Vec2(0.25f, 0.25f)), Vec3(0, 0, 1), 1e-6f, "bottom-left by uv");

  // The tinted quad's texture coordinates equal its x and y, so the point
  // (0.25, 0.75) is the centre of the top-left texel: albedo = Kd x red.
  int found = 0;
  for (uint32_t t : TrianglesOf(*scene, "tinted")) {
    const auto b = Barycentrics(*scene, t, Vec3(0.25f, 0.75f, 0.0f));
    if (!b) continue;
    ++found;
    ExpectNear(scene->AlbedoAt(t, (*b)[0], (*b)[1]), Vec3(0.5f, 0.0f, 0.0f), 1e-5f);
  }
  EXPECT_EQ(found, 1);
}

TEST(SceneLoaderTest, FloatTexturesAreTakenAsLinear) {
  ScratchDir dir;
  ASSERT_TRUE(WriteImage(dir / "linear.exr", 1, 1, std::vector<float>{0.5f, 0.25f, 2.0f}).ok());
  dir.Write("quad.mtl", "newmtl m\nKd 1 1 1\nmap_Kd linear.exr\n");
  dir.Write("quad.obj", "mtllib quad.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nusemtl m\nf 1/1 2/2 3/3\n");
  auto scene = LoadScene(dir / "quad.obj");
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  ASSERT_EQ(scene->textures.size(), 1u);
  ExpectNear(scene->textures[0].texels[0], Vec3(0.5f, 0.25f, 2.0f), 0.0f);
}

// --- glTF -------------------------------------------------------------------

class GltfTest : public ::testing::TestWithParam<const char*> {};

TEST_P(GltfTest, BaseColourTextureEmissionAndNodeTransformsAreImported) {
  auto scene = LoadScene(TestData(GetParam()));
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  EXPECT_EQ(scene->triangles.size(), 3u);
  // glTF's default material is unused and not imported.
  ASSERT_EQ(scene->materials.size(), 2u);

  const Material* textured = FindMaterial(*scene, "textured");
  ASSERT_NE(textured, nullptr);
  ExpectNear(textured->albedo, Vec3(0.5f, 1.0f, 1.0f), 0.0f);
  ASSERT_EQ(textured->albedoTexture, 0);
  const Texture& texture = scene->textures[0];
  ASSERT_EQ(texture.width, 2);
  ExpectNear(texture.texels[3], Vec3(kLinearOfSrgb128), 1e-6f, "embedded PNG decoded from sRGB");

  // Node transforms: root translation (0,1,0) x quad scale 2 -> the quad spans
  // x 0..2, y 1..3 in z = 0. glTF puts uv (0,0) at the image's top-left;
  // after import v = 1 is the top of the image, as for OBJ.
  for (uint32_t t : TrianglesOf(*scene, "textured")) {
    for (int c = 0; c < 3; ++c) {
      const Vec3& p = scene->Position(t, c);
      EXPECT_TRUE(p.x >= 0 && p.x <= 2 && p.y >= 1 && p.y <= 3 && p.z == 0) << p.x << " " << p.y << " " << p.z;
      const Vec2 uv = scene->triangles[t].uv[c];
      EXPECT_NEAR(uv.x, p.x / 2, 1e-6f);
      EXPECT_NEAR(uv.y, (p.y - 1) / 2, 1e-6f);
    }
  }
  ExpectNear(texture.Sample(Vec2(0.25f, 0.75f)), Vec3(1, 0, 0), 1e-6f, "top-left texel is red");

  // emissiveFactor (1, 0.5, 0.25) x KHR_materials_emissive_strength 4.
  const Material* lamp = FindMaterial(*scene, "lamp");
  ASSERT_NE(lamp, nullptr);
  ExpectNear(lamp->emission, Vec3(4, 2, 1), 1e-6f);
  ExpectNear(lamp->albedo, Vec3(0), 0.0f);
  ASSERT_EQ(scene->emissiveTriangles.size(), 1u);
  const uint32_t lampTriangle = scene->emissiveTriangles[0];
  for (int c = 0; c < 3; ++c) EXPECT_EQ(scene->Position(lampTriangle, c).z, -1.0f);  // translated by (0,1,-1)
  ExpectNear(scene->GeometricNormal(lampTriangle), Vec3(0, 0, 1), 1e-6f);
}

INSTANTIATE_TEST_SUITE_P(TextAndBinary, GltfTest, ::testing::Values("two_materials.gltf", "two_materials.glb"));

// --- Scene files -------------------------------------------------------------

TEST(SceneFileTest, FullSceneFileSetsEverything) {
  auto scene = LoadScene(TestData("full_scene.json"));
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  EXPECT_EQ(scene->name, "lamp-room");

  // Materials: overridden albedo; the mesh's emission x emission_scale 2; an
  // emission override is absolute.
  ExpectNear(FindMaterial(*scene, "floor")->albedo, Vec3(0.25f, 0.5f, 0.75f), 0.0f);
  ExpectNear(FindMaterial(*scene, "lamp")->emission, Vec3(4.0f), 0.0f);
  ExpectNear(FindMaterial(*scene, "lamp2")->emission, Vec3(1, 0, 0), 0.0f);

  // The quad light: two emissive triangles facing cross(edge1, edge2) = +z,
  // with the given radiance (emission_scale does not apply to it).
  const auto panel = TrianglesOf(*scene, "panel");
  ASSERT_EQ(panel.size(), 2u);
  float area = 0.0f;
  for (uint32_t t : panel) {
    ExpectNear(scene->GeometricNormal(t), Vec3(0, 0, 1), 1e-6f);
    ExpectNear(scene->MaterialOf(t).emission, Vec3(5, 4, 3), 0.0f);
    EXPECT_NE(std::find(scene->emissiveTriangles.begin(), scene->emissiveTriangles.end(), t),
              scene->emissiveTriangles.end());
    area += scene->Area(t);
  }
  EXPECT_NEAR(area, 1.0f, 1e-6f);
  EXPECT_EQ(scene->emissiveTriangles.size(), 2u + 1u + 2u);  // lamp, lamp2, panel

  // Sun from elevation 30 / azimuth 90: toward +x and up. Its irradiance at
  // normal incidence is what the file gave; its radiance is that over the
  // solid angle of a 1-degree disc.
  ASSERT_TRUE(scene->sun.has_value());
  ExpectNear(scene->sun->directionToSun, Vec3(std::cos(kPi / 6), 0.5f, 0.0f), 1e-6f);
  EXPECT_NEAR(scene->sun->angularDiameterRad, kPi / 180.0f, 1e-7f);
  ExpectNear(scene->sun->NormalIrradiance(), Vec3(3, 2, 1), 1e-4f);
  const float solidAngle = 2.0f * kPi * (1.0f - std::cos(0.5f * kPi / 180.0f));
  EXPECT_NEAR(scene->sun->radiance.r, 3.0f / solidAngle, 1e-3f * 3.0f / solidAngle);

  ASSERT_TRUE(scene->sky.has_value());
  ExpectNear(scene->sky->up, Vec3(0, 1, 0), 0.0f, "up is normalised");
  ExpectNear(scene->sky->zenith, Vec3(0.1f, 0.2f, 0.4f), 0.0f);
  ExpectNear(scene->sky->horizon, Vec3(0.3f), 0.0f);
  ExpectNear(scene->sky->ground, Vec3(0.05f, 0.04f, 0.03f), 0.0f);

  // Cameras in file order; unspecified up and fov take their defaults.
  ASSERT_EQ(scene->cameras.size(), 2u);
  EXPECT_EQ(scene->cameras[0].name, "overview");
  EXPECT_EQ(scene->cameras[0].fovYDeg, 50.0f);
  ExpectNear(scene->cameras[0].pose.eye, Vec3(0, 3, 4), 0.0f);
  EXPECT_EQ(scene->cameras[1].name, "closeup");
  EXPECT_EQ(scene->cameras[1].fovYDeg, 45.0f);
  ExpectNear(scene->cameras[1].pose.up, Vec3(0, 1, 0), 0.0f);

  // Paths: inline, and from a file whose own "name" the scene's key overrides.
  ASSERT_EQ(scene->paths.size(), 2u);
  EXPECT_EQ(scene->paths[0].name, "inline");
  EXPECT_EQ(scene->paths[0].fovYDeg, 40.0f);
  ASSERT_NE(scene->FindPath("dolly"), nullptr);
  const CameraPath& dolly = *scene->FindPath("dolly");
  EXPECT_EQ(dolly.width, 320);
  EXPECT_EQ(dolly.keyframes.size(), 2u);
  EXPECT_DOUBLE_EQ(dolly.DurationSeconds(), 2.0);
}

// A path that tilts from looking down one way to looking down the other
// passes through looking straight down, along its up: every pose on it must
// still be a valid view, whose up is perpendicular to it at the crossing.
TEST(CameraPathTest, APathThroughTheVerticalStaysAValidView) {
  CameraPath path;
  path.keyframes.push_back({0.0, CameraPose{Vec3(0.0f, 10.0f, 0.0f), Vec3(1.0f, 0.0f, 0.0f), Vec3(0.0f, 1.0f, 0.0f)}});
  path.keyframes.push_back({1.0, CameraPose{Vec3(0.0f, 10.0f, 0.0f), Vec3(-1.0f, 0.0f, 0.0f), Vec3(0.0f, 1.0f, 0.0f)}});
  // And a segment whose up turns too, crossing the view direction twice.
  path.keyframes.push_back({2.0, CameraPose{Vec3(0.0f, 10.0f, 0.0f), Vec3(0.0f, 20.0f, 0.0f), Vec3(1.0f, 0.0f, 0.0f)}});
  for (int i = 0; i <= 2000; ++i) {
    const double t = i / 1000.0;
    const CameraView view = path.ViewAt(t);
    ASSERT_TRUE(ValidateCameraView(view).ok()) << "t = " << t << ": " << ValidateCameraView(view).error().message;
  }
  const CameraPose down = path.PoseAt(0.5);
  EXPECT_EQ(down.target, Vec3(0.0f, 0.0f, 0.0f)) << "straight down";
  EXPECT_NEAR(glm::dot(glm::normalize(down.up), Vec3(0.0f, -1.0f, 0.0f)), 0.0f, 1e-6f);
  EXPECT_NEAR(std::abs(down.up.x), 1.0f, 1e-6f) << "up along the way the camera was heading";
  const CameraPose before = path.PoseAt(0.25);
  EXPECT_EQ(before.up, Vec3(0.0f, 1.0f, 0.0f)) << "left alone away from the crossing";
}

TEST(SceneFileTest, CreaseAngleInTheFileOverridesTheOption) {
  ScratchDir dir;
  const std::string mesh = CornellBoxObj().string();
  auto sharp = LoadScene(dir.Write("sharp.json", R"({"mesh": ")" + mesh + R"(", "crease_angle_deg": 10})"));
  auto smooth = LoadScene(dir.Write("smooth.json", R"({"mesh": ")" + mesh + R"(", "crease_angle_deg": 100})"));
  ASSERT_TRUE(sharp.ok()) << sharp.error().message;
  ASSERT_TRUE(smooth.ok()) << smooth.error().message;
  EXPECT_LT(smooth->vertices.size(), sharp->vertices.size());
  EXPECT_EQ(smooth->name, "smooth");  // no "name": the file's stem
}

TEST(SceneFileTest, SunByDirectionAndRadianceAndUniformSky) {
  ScratchDir dir;
  const auto file = dir.Write("sun.json", R"({
    "mesh": ")" + TestData("lamp_room.obj").string() + R"(",
    "sun": {"direction": [0, 2, 2], "radiance": [1000, 900, 800]},
    "sky": {"radiance": [0.5, 0.6, 0.7]}
  })");
  auto scene = LoadScene(file);
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  ExpectNear(scene->sun->directionToSun, glm::normalize(Vec3(0, 1, 1)), 1e-6f);
  ExpectNear(scene->sun->radiance, Vec3(1000, 900, 800), 0.0f);
  EXPECT_NEAR(scene->sun->angularDiameterRad, 0.53f * kPi / 180.0f, 1e-7f);  // the default
  for (const Vec3& d : {Vec3(0, 1, 0), Vec3(1, 0, 0), Vec3(0, -1, 0)})
    ExpectNear(scene->sky->Radiance(d), Vec3(0.5f, 0.6f, 0.7f), 1e-6f);
}

// --- Bad input: an Error naming the file and the problem, never a crash ------

struct BadInput {
  const char* label;
  // Makes the bad file (in `dir` or among the fixtures) and returns its path.
  std::function<fs::path(const ScratchDir& dir)> make;
  const char* problem;  // a fragment the message must contain
};

// A scene file around `body` (the members after "mesh") in `dir`.
fs::path SceneJson(const ScratchDir& dir, const std::string& body) {
  return dir.Write("scene.json", R"({"mesh": ")" + TestData("lamp_room.obj").string() + "\"" + body + "}");
}

const BadInput kBadInputs[] = {
    {"MissingFile", [](const ScratchDir& d) { return d / "absent.obj"; }, "no such file"},
    {"Directory", [](const ScratchDir& d) { return d.path(); }, "not a regular file"},
    {"DirectoryNamedObj", [](const ScratchDir& d) { fs::create_directory(d / "dir.obj"); return d / "dir.obj"; },
     "not a regular file"},
    {"EmptyObj", [](const ScratchDir&) { return TestData("bad/empty.obj"); }, "too small"},
    {"NanVertex", [](const ScratchDir&) { return TestData("bad/nan_vertex.obj"); }, "non-finite"},
    {"InfiniteVertex", [](const ScratchDir& d) { return d.Write("inf.obj", "v 0 0 0\nv 1e40 1 0\nv 0 1 0\nf 1 2 3\n"); },
     "non-finite"},
    {"FaceIndexOutOfRange", [](const ScratchDir&) { return TestData("bad/face_index_out_of_range.obj"); },
     "out of range"},
    {"NegativeIndexOutOfRange", [](const ScratchDir&) { return TestData("bad/negative_index_out_of_range.obj"); },
     "out of range"},
    {"MissingTexture", [](const ScratchDir&) { return TestData("bad/missing_texture.obj"); }, "no_such_texture.png"},
    {"MissingMtl", [](const ScratchDir&) { return TestData("bad/missing_mtl.obj"); }, "no_such_library.mtl"},
    {"OnlyDegenerateTriangles", [](const ScratchDir& d) { return d.Write("flat.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n"); },
     "no triangles"},
    {"OnlyPoints", [](const ScratchDir& d) { return d.Write("points.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\np 1 2 3\n"); },
     "no triangles"},
    {"UnreadableTexture",
     [](const ScratchDir& d) {
       d.Write("garbage.png", "this is not a PNG");
       d.Write("m.mtl", "newmtl m\nmap_Kd garbage.png\n");
       return d.Write("m.obj", "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl m\nf 1 2 3\n");
     },
     "garbage.png"},
    {"UnknownFormat", [](const ScratchDir& d) { return d.Write("mesh.xyz123", "whatever"); }, "mesh.xyz123"},
    {"GltfWithMissingBuffer",
     [](const ScratchDir& d) {
       return d.Write("b.gltf", R"({"asset": {"version": "2.0"}, "buffers": [{"uri": "absent.bin", "byteLength": 12}]})");
     },
     "b.gltf"},
    // Scene files.
    {"JsonMissingMesh", [](const ScratchDir&) { return TestData("bad/missing_mesh.json"); }, "no_such_mesh.obj"},
    {"JsonEmpty", [](const ScratchDir& d) { return d.Write("empty.json", ""); }, "not valid JSON"},
    {"JsonMalformed", [](const ScratchDir& d) { return d.Write("bad.json", R"({"mesh": "x.obj",)"); }, "line 1"},
    {"JsonNotAnObject", [](const ScratchDir& d) { return d.Write("list.json", "[1, 2]"); }, "JSON object"},
    {"JsonNoMesh", [](const ScratchDir& d) { return d.Write("nomesh.json", "{}"); }, "missing \"mesh\""},
    {"JsonUnknownTopLevelKey", [](const ScratchDir& d) { return SceneJson(d, R"(, "camras": {})"); },
     "unknown key \"camras\""},
    {"JsonUnknownSunKey",
     [](const ScratchDir& d) {
       return SceneJson(d, R"(, "sun": {"direction": [0, 1, 0], "irradience": [1, 1, 1]})");
     },
     "sun: unknown key \"irradience\""},
    {"JsonSunWithoutPower", [](const ScratchDir& d) { return SceneJson(d, R"(, "sun": {"direction": [0, 1, 0]})"); },
     "\"radiance\" or \"irradiance\""},
    {"JsonSunWithTwoDirections",
     [](const ScratchDir& d) {
       return SceneJson(d, R"(, "sun": {"direction": [0, 1, 0], "elevation_deg": 30, "azimuth_deg": 0,
                                        "radiance": [1, 1, 1]})");
     },
     "either"},
    {"JsonSunZeroDirection",
     [](const ScratchDir& d) { return SceneJson(d, R"(, "sun": {"direction": [0, 0, 0], "radiance": [1, 1, 1]})"); },
     "must not be zero"},
    {"JsonNegativeRadiance",
     [](const ScratchDir& d) { return SceneJson(d, R"(, "sky": {"radiance": [1, -1, 1]})"); }, "non-negative"},
    {"JsonOverflowingNumber",
     [](const ScratchDir& d) { return SceneJson(d, R"(, "sky": {"radiance": [1, 1e39, 1]})"); }, "sky"},
    {"JsonHugeNumber", [](const ScratchDir& d) { return SceneJson(d, R"(, "emission_scale": 1e999)"); },
     "not valid JSON"},
    {"JsonStringForNumber", [](const ScratchDir& d) { return SceneJson(d, R"(, "crease_angle_deg": "40")"); },
     "crease_angle_deg"},
    {"JsonSkyHalfGradient",
     [](const ScratchDir& d) { return SceneJson(d, R"(, "sky": {"zenith": [1, 1, 1], "horizon": [1, 1, 1]})"); },
     "\"ground\""},
    {"JsonDegenerateQuad",
     [](const ScratchDir& d) {
       return SceneJson(d, R"(, "quad_lights": [{"name": "q", "corner": [0, 0, 0], "edge1": [1, 0, 0],
                                                  "edge2": [2, 0, 0], "radiance": [1, 1, 1]}])");
     },
     "quad_lights[0]"},
    {"JsonQuadWithoutName",
     [](const ScratchDir& d) {
       return SceneJson(d, R"(, "quad_lights": [{"corner": [0, 0, 0], "edge1": [1, 0, 0], "edge2": [0, 1, 0],
                                                  "radiance": [1, 1, 1]}])");
     },
     "missing \"name\""},
    {"JsonUnknownMaterial",
     [](const ScratchDir& d) { return SceneJson(d, R"(, "materials": {"flor": {"albedo": [1, 1, 1]}})"); },
     "\"flor\""},
    {"JsonAlbedoAboveOne",
     [](const ScratchDir& d) { return SceneJson(d, R"(, "materials": {"floor": {"albedo": [1.5, 1, 1]}})"); },
     "materials.floor"},
    {"JsonCameraEyeAtTarget",
     [](const ScratchDir& d) { return SceneJson(d, R"(, "cameras": {"c": {"eye": [1, 1, 1], "target": [1, 1, 1]}})"); },
     "cameras.c"},
    {"JsonCameraFovOutOfRange",
     [](const ScratchDir& d) {
       return SceneJson(d, R"(, "cameras": {"c": {"eye": [0, 0, 1], "target": [0, 0, 0], "fov_y_deg": 200}})");
     },
     "fov_y_deg"},
    {"JsonPathKeyframeTypo",
     [](const ScratchDir& d) {
       return SceneJson(d, R"(, "paths": {"p": {"keyframes": [{"t": 0, "eye": [0, 0, 1], "taget": [0, 0, 0]}]}})");
     },
     "unknown key \"taget\""},
    {"JsonPathWithoutKeyframes", [](const ScratchDir& d) { return SceneJson(d, R"(, "paths": {"p": {}})"); },
     "keyframes"},
    {"JsonMissingPathFile",
     [](const ScratchDir& d) { return SceneJson(d, R"(, "paths": {"p": {"file": "absent_path.json"}})"); },
     "absent_path.json"},
};

// One test for the whole table: each case would otherwise be a process of its
// own under ctest, and OpenImageIO makes every process start cost ~0.3 s.
TEST(SceneLoaderTest, EveryBadInputIsAnErrorNamingTheFileAndTheProblem) {
  for (const BadInput& input : kBadInputs) {
    SCOPED_TRACE(input.label);
    ScratchDir dir;
    const fs::path file = input.make(dir);
    auto scene = LoadScene(file);
    ASSERT_FALSE(scene.ok()) << file << " loaded";
    const std::string& message = scene.error().message;
    EXPECT_NE(message.find(file.filename().string()), std::string::npos) << message;
    EXPECT_NE(message.find(input.problem), std::string::npos) << message;
    EXPECT_EQ(message.find('\n'), std::string::npos) << "one line: " << message;
  }
}

// Truncated and random files either load or fail with a message naming the
// file -- never crash, throw or hang.
void ExpectLoadsOrNamesTheFile(const fs::path& file) {
  auto scene = LoadScene(file);
  if (!scene.ok()) {
    EXPECT_NE(scene.error().message.find(file.filename().string()), std::string::npos) << scene.error().message;
  }
}

TEST(SceneLoaderTest, TruncatedFilesNeverCrash) {
  ScratchDir dir;
  fs::copy_file(SourceDir() / "scenes/cornell-box/CornellBox-Original.mtl", dir / "CornellBox-Original.mtl");
  const std::string obj = ReadFile(CornellBoxObj());
  const std::string gltf = ReadFile(TestData("two_materials.gltf"));
  const std::string glb = ReadFile(TestData("two_materials.glb"));
  const std::string json = ReadFile(TestData("full_scene.json"));
  for (size_t cut = 0; cut < obj.size(); cut += 61) ExpectLoadsOrNamesTheFile(dir.Write("cut.obj", obj.substr(0, cut)));
  for (size_t cut = 0; cut < gltf.size(); cut += 97) ExpectLoadsOrNamesTheFile(dir.Write("cut.gltf", gltf.substr(0, cut)));
  for (size_t cut = 0; cut < glb.size(); cut += 53) ExpectLoadsOrNamesTheFile(dir.Write("cut.glb", glb.substr(0, cut)));
  for (size_t cut = 0; cut < json.size(); cut += 41) ExpectLoadsOrNamesTheFile(dir.Write("cut.json", json.substr(0, cut)));
}

TEST(SceneLoaderTest, RandomBytesNeverCrash) {
  ScratchDir dir;
  std::mt19937 random(1234);
  std::uniform_int_distribution<int> byte(0, 255);
  for (const char* name : {"random.obj", "random.gltf", "random.glb", "random.ply", "random.stl", "random.json"}) {
    for (int trial = 0; trial < 4; ++trial) {
      std::string bytes(size_t(500 + 1500 * trial), '\0');
      for (char& c : bytes) c = char(byte(random));
      const fs::path file = dir.Write(name, bytes);
      auto scene = LoadScene(file);
      ASSERT_FALSE(scene.ok()) << name << " trial " << trial << " loaded";
      EXPECT_NE(scene.error().message.find(name), std::string::npos) << scene.error().message;
    }
  }
}

std::string Le32(uint32_t v) {
  return std::string{char(v & 0xff), char((v >> 8) & 0xff), char((v >> 16) & 0xff), char(v >> 24)};
}

// The attack run's 24-byte GLB declaring a 2 GB chunk took 13.6 s and
// 2.1 GiB before its error: declared sizes are checked against the file
// before assimp reads it.
TEST(SceneLoaderTest, GlbDeclaringMoreBytesThanItHasIsRefusedBeforeReading) {
  ScratchDir dir;
  const long rssBefore = testing::PeakRssMiB();
  const std::string json = Le32(0x4E4F534Au);  // "JSON"
  const fs::path chunk =
      dir.Write("chunk.glb", "glTF" + Le32(2) + Le32(24) + Le32(2000000000u) + json + std::string(4, ' '));
  auto scene = LoadScene(chunk);
  ASSERT_FALSE(scene.ok());
  EXPECT_NE(scene.error().message.find("chunk.glb: GLB chunk 0 declares 2000000000 bytes but only 4 follow"),
            std::string::npos)
      << scene.error().message;
  const fs::path total = dir.Write("total.glb", "glTF" + Le32(2) + Le32(0x7fffffffu) + Le32(2) + json + "{}");
  scene = LoadScene(total);
  ASSERT_FALSE(scene.ok());
  EXPECT_NE(scene.error().message.find("total.glb: the GLB header declares 2147483647 bytes but the file has 22"),
            std::string::npos)
      << scene.error().message;
  // Found by fuzz_scene_gltf: a total length too short for the first chunk's
  // header, which assimp then read anyway (and allocated its 2 GB).
  const fs::path shortHeader =
      dir.Write("short.glb", "glTF" + Le32(2) + Le32(19) + Le32(0x80000758u) + json + "{\"asset\": {}}");
  scene = LoadScene(shortHeader);
  ASSERT_FALSE(scene.ok());
  EXPECT_NE(scene.error().message.find("short.glb: the GLB header declares 19 bytes, too few for its JSON chunk"),
            std::string::npos)
      << scene.error().message;
  EXPECT_LT(testing::PeakRssMiB() - rssBefore, 64) << "MiB taken by refused files";
  // The committed GLB (chunks that fit) still loads.
  EXPECT_TRUE(LoadScene(TestData("two_materials.glb")).ok());
}

// A texture whose header declares more than kMaxImageBytes of decoded
// pixels fails the scene with the texture named, without allocating them.
TEST(SceneLoaderTest, TextureThatWouldDecodeTooLargeFailsTheSceneBeforeAllocating) {
  ScratchDir dir;
  const std::string quad =
      "v 0 0 0\nv 1 0 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nusemtl tex\nf 1/1 2/2 3/3\n";
  // The loader's first use (Assimp, the image decoder, and under
  // ThreadSanitizer their shadow memory: 85 MiB) is paid before measuring.
  dir.Write("small.png", testing::PngDeclaringSize(16, 16));
  dir.Write("warm.mtl", "newmtl tex\nKd 1 1 1\nmap_Kd small.png\n");
  (void)LoadScene(dir.Write("warm.obj", "mtllib warm.mtl\n" + quad));
  const long rssBefore = testing::PeakRssMiB();
  dir.Write("big.png", testing::PngDeclaringSize(8192, 8191));
  dir.Write("quad.mtl", "newmtl tex\nKd 1 1 1\nmap_Kd big.png\n");
  const fs::path obj = dir.Write("quad.obj", "mtllib quad.mtl\n" + quad);
  auto scene = LoadScene(obj);
  ASSERT_FALSE(scene.ok());
  EXPECT_NE(scene.error().message.find("big.png: image of 8192x8191 pixels would take 767 MiB decoded"),
            std::string::npos)
      << scene.error().message;
  EXPECT_LT(testing::PeakRssMiB() - rssBefore, 64) << "MiB taken by the refused texture";
}

// Assimp 5.2.4 crashes (SEGV) on these files, found by fuzz_scene_obj and
// fuzz_scene_gltf (tests/fuzz/corpus/): LoadScene reports an error naming
// the file, and this process lives on.
TEST(SceneLoaderTest, FilesThatCrashAssimpAreAnErrorNotACrash) {
  ScratchDir dir;
  const fs::path corpus = SourceDir() / "tests/fuzz/corpus";
  // The OBJ target's input: the OBJ, then "%%MTL%%" and the MTL it names.
  const std::string objInput = ReadFile(corpus / "fuzz_scene_obj/crash-assimp-segv-obj-reader");
  const size_t split = objInput.find("\n%%MTL%%\n");
  ASSERT_NE(split, std::string::npos);
  dir.Write("fuzz.mtl", objInput.substr(split + 9));
  const fs::path obj = dir.Write("fuzz.obj", objInput.substr(0, split));
  const fs::path glb =
      dir.Write("fuzz.glb", ReadFile(corpus / "fuzz_scene_gltf/crash-assimp-segv-glb-image-mime-type"));
  for (const fs::path& file : {obj, glb}) {
    auto scene = LoadScene(file);
    ASSERT_FALSE(scene.ok()) << file;
    EXPECT_NE(scene.error().message.find(file.filename().string() + ": the mesh reader (assimp) crashed on this file"),
              std::string::npos)
        << scene.error().message;
  }
  // A file assimp reads well still loads (the probe does not get in the way).
  EXPECT_TRUE(LoadScene(TestData("two_materials.glb")).ok());
}

// --- The repository's default scene ------------------------------------------

TEST(RepositoryScenesTest, CornellBoxSceneHasItsLightCamerasAndPaths) {
  auto scene = LoadScene(SourceDir() / "scenes/cornell-box.json");
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  EXPECT_EQ(scene->name, "cornell-box");
  EXPECT_EQ(scene->emissiveTriangles.size(), 2u);
  ASSERT_GE(scene->cameras.size(), 2u);
  EXPECT_EQ(scene->cameras[0].name, "front");
  ASSERT_NE(scene->FindPath("orbit"), nullptr);
  ASSERT_NE(scene->FindPath("walk"), nullptr);

  // The front camera looks into the open side (+z) and sees the light.
  const CameraPreset& front = scene->cameras[0];
  EXPECT_GT(front.pose.eye.z, scene->bounds.max.z);
  const RayCaster caster(*scene);
  const uint32_t light = scene->emissiveTriangles[0];
  const Vec3 toLight = scene->PointAt(light, 1.0f / 3, 1.0f / 3) - front.pose.eye;
  const auto hit = caster.Intersect(front.pose.eye, glm::normalize(toLight));
  ASSERT_TRUE(hit.has_value());
  EXPECT_EQ(scene->MaterialOf(hit->triangle).name, "light");
  for (const CameraPath& path : scene->paths) ExpectPathIsClear(*scene, caster, path);
}

// A closed room (all six faces of a box, 8 x 3 x 4, facing in), as OBJ.
std::string RoomObj() {
  return "v 0 0 0\nv 8 0 0\nv 8 0 4\nv 0 0 4\nv 0 3 0\nv 8 3 0\nv 8 3 4\nv 0 3 4\n"
         "f 1 2 3 4\nf 5 8 7 6\nf 1 5 6 2\nf 3 7 8 4\nf 1 4 8 5\nf 2 6 7 3\n";
}

// Issue 16: the made-up camera of a mesh-only building stands inside it, at
// eye height, looking along its length at a wall -- not outside the walls.
TEST(SceneLoaderTest, AMeshOnlyBuildingGetsACameraInsideLookingAlongIt) {
  ScratchDir dir;
  auto scene = LoadScene(dir.Write("room.obj", RoomObj()));
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  ASSERT_EQ(scene->cameras.size(), 2u);
  const CameraPreset& inside = scene->cameras[0];
  EXPECT_EQ(inside.name, "inside");
  EXPECT_EQ(scene->cameras[1].name, "default") << "the overview stays, as preset 2";
  const Vec3& eye = inside.pose.eye;
  for (int i = 0; i < 3; ++i) {
    EXPECT_GT(eye[i], scene->bounds.min[i]) << "axis " << i;
    EXPECT_LT(eye[i], scene->bounds.max[i]) << "axis " << i;
  }
  EXPECT_NEAR(eye.y, 0.75f, 1e-4f) << "a quarter of the way up";
  const Vec3 forward = glm::normalize(inside.pose.target - inside.pose.eye);
  EXPECT_NEAR(forward.x, 1.0f, 1e-4f) << "along the longer horizontal extent";
  // It looks at something: the far wall, most of the room's length away.
  const RayCaster caster(*scene);
  const auto hit = caster.Intersect(eye, forward);
  ASSERT_TRUE(hit.has_value());
  EXPECT_GT(hit->distance, 4.0f);
  CameraView view;
  view.pose = inside.pose;
  view.fovYDeg = inside.fovYDeg;
  EXPECT_TRUE(ValidateCameraView(view).ok());
}

TEST(SceneLoaderTest, AnObjectSeenFromOutsideKeepsTheFramingView) {
  // The Cornell box is open at the front: not a building to stand in.
  auto scene = LoadScene(CornellBoxObj());
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  ASSERT_EQ(scene->cameras.size(), 1u);
  EXPECT_EQ(scene->cameras[0].name, "default");
}

// Issue 16: a mesh without emitters, sun or sky renders black; LoadScene
// loads it (and warns) -- HasLight is what the warning tests.
TEST(SceneLoaderTest, AMeshWithoutAnyLightLoadsAndSaysItHasNone) {
  ScratchDir dir;
  const auto stl = dir.Write("triangle.stl",
                             "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\n"
                             "endloop\nendfacet\nendsolid t\n");
  auto scene = LoadScene(stl);
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  EXPECT_FALSE(scene->HasLight());
  auto room = LoadScene(dir.Write("room.obj", RoomObj()));
  ASSERT_TRUE(room.ok());
  EXPECT_FALSE(room->HasLight());
  auto cornell = LoadScene(CornellBoxObj());
  ASSERT_TRUE(cornell.ok());
  EXPECT_TRUE(cornell->HasLight());
}

// --- The shared real-world scenes (../shared/scenes beside the source tree) ---


#define SKIP_WITHOUT_SHARED_SCENE(relative)                                                          \
  if (!fs::exists(SharedScene(relative)))                                                            \
  GTEST_SKIP() << SharedScene(relative).lexically_normal() << " is absent (clone ../shared beside " \
               << "the source tree to run this test)"

// Each of these loads its scene once (ctest runs every test in its own process)
// and checks everything about it.
TEST(SharedScenesTest, SponzaLoadsAndTheSunCastsThePiersShadowsOnTheAtriumFloor) {
  SKIP_WITHOUT_SHARED_SCENE("sponza-dabrovic/sponza.obj");
  auto scene = LoadScene(SourceDir() / "scenes/sponza.json");
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  // SOURCE.md: 66,973 triangles (none degenerate here), 20 materials, 10 textures.
  EXPECT_NEAR(double(scene->triangles.size()), 66973.0, 10.0);
  EXPECT_EQ(scene->materials.size(), 20u);
  EXPECT_EQ(scene->textures.size(), 10u);
  // 66,662 vertices in the file; welding UV seams and splitting creases
  // changes that, but not by an order of magnitude.
  EXPECT_NE(scene->vertices.size(), 66662u);
  EXPECT_GT(scene->vertices.size(), 30000u);
  EXPECT_LT(scene->vertices.size(), 200000u);
  EXPECT_TRUE(scene->emissiveTriangles.empty()) << "the sphere light is switched off";
  ASSERT_TRUE(scene->sun.has_value());
  ASSERT_TRUE(scene->sky.has_value());
  ASSERT_EQ(scene->cameras[0].name, "atrium");

  const RayCaster caster(*scene);
  // Down the ground-floor corridor behind the +z arcade (docs/scenes.md): the
  // sun comes in through the roof opening and under the arches, and the piers
  // between the arches cut its light into patches.
  int transitions = 0, lit = 0, samples = 0;
  std::optional<bool> previous;
  for (float x = -11.0f; x <= 5.0f; x += 0.1f, ++samples) {
    const auto floor = caster.Intersect(Vec3(x, 1.0f, 2.8f), Vec3(0, -1, 0));
    ASSERT_TRUE(floor.has_value());
    ASSERT_EQ(scene->MaterialOf(floor->triangle).name, "sp_00_pod");
    const bool sunlit = SunVisible(*scene, caster, Vec3(0, -1, 0), Vec3(x, 1.0f - floor->distance, 2.8f), floor->triangle);
    lit += sunlit;
    transitions += previous && *previous != sunlit;
    previous = sunlit;
  }
  EXPECT_GT(lit, samples / 4);
  EXPECT_GE(transitions, 6) << "three piers stand on this stretch";

  // The atrium camera sees sunlit floor.
  EXPECT_GT(SunlitFraction(*scene, caster, scene->cameras[0], "sp_00_pod", 32, 24), 0.05);
  for (const CameraPath& path : scene->paths) ExpectPathIsClear(*scene, caster, path);
}

// The mesh alone (no scene file, so no presets): the made-up camera stands in
// the atrium and sees the building.
TEST(SharedScenesTest, SponzaAsAMeshAloneGetsACameraInsideTheAtrium) {
  SKIP_WITHOUT_SHARED_SCENE("sponza-dabrovic/sponza.obj");
  auto scene = LoadScene(SharedScene("sponza-dabrovic/sponza.obj"));
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  ASSERT_GE(scene->cameras.size(), 2u);
  const CameraPreset& inside = scene->cameras[0];
  ASSERT_EQ(inside.name, "inside");
  for (int i = 0; i < 3; ++i) {
    EXPECT_GT(inside.pose.eye[i], scene->bounds.min[i]);
    EXPECT_LT(inside.pose.eye[i], scene->bounds.max[i]);
  }
  const RayCaster caster(*scene);
  const Vec3 forward = glm::normalize(inside.pose.target - inside.pose.eye);
  const auto hit = caster.Intersect(inside.pose.eye, forward);
  ASSERT_TRUE(hit.has_value()) << "looks at something";
  EXPECT_GT(hit->distance, 0.25f * glm::length(scene->bounds.Diagonal())) << "down the atrium, not at a pillar";
  // Not inside a wall: the floor is below and something is above or beside.
  EXPECT_TRUE(caster.Intersect(inside.pose.eye, Vec3(0, -1, 0)).has_value());
}

TEST(SharedScenesTest, BreakfastRoomLoadsAndTheSunComesInThroughTheWindow) {
  SKIP_WITHOUT_SHARED_SCENE("breakfast-room/breakfast-room.obj");
  auto scene = LoadScene(SourceDir() / "scenes/breakfast-room.json");
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  // SOURCE.md: 269,538 triangles, 15 materials, 3 textures, no emitters.
  EXPECT_NEAR(double(scene->triangles.size()), 269538.0, 50.0);
  EXPECT_EQ(scene->materials.size(), 15u);
  EXPECT_EQ(scene->textures.size(), 3u);
  EXPECT_NE(scene->vertices.size(), 142720u);
  EXPECT_GT(scene->vertices.size(), 70000u);
  EXPECT_LT(scene->vertices.size(), 500000u);
  EXPECT_TRUE(scene->emissiveTriangles.empty());
  ASSERT_TRUE(scene->sun.has_value());
  ASSERT_EQ(scene->cameras[0].name, "source");

  // Sunlight through the blinds lands on the floor and on the table.
  const RayCaster caster(*scene);
  const CameraPreset* table = scene->FindCamera("table");
  ASSERT_NE(table, nullptr);
  EXPECT_GT(SunlitFraction(*scene, caster, *table, "FloorTiles", 24, 14) +
                SunlitFraction(*scene, caster, *table, "WhiteMarble", 24, 14),
            0.02);
  for (const CameraPath& path : scene->paths) ExpectPathIsClear(*scene, caster, path);
}

}  // namespace
}  // namespace penumbra
