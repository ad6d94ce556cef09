// Static instances in scene files (issue 15, docs/scenes.md "Instances"):
// copies of a mesh file placed by rigid transforms, each its own triangles
// and vertices in the static part; the mesh read once; every bound and every
// bad entry an error naming the file and the field.

#include <cmath>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include "penumbra/common/scene.h"
#include "test_files.h"

namespace penumbra {
namespace {

namespace fs = std::filesystem;
using testing::CornellBoxObj;
using testing::ScratchDir;
using testing::SourceDir;


// A scene file in `dir` whose main mesh is the Cornell box and whose
// "instances" value is `instances` (JSON text).
fs::path WriteSceneWithInstances(const ScratchDir& dir, const std::string& instances,
                                 const std::string& extra = "") {
  return dir.Write("street.json", fmt::format(R"({{"mesh": "{}", "instances": {}{}}})", CornellBoxObj().string(),
                                              instances, extra));
}

TEST(SceneInstancesTest, AQuadOfRadianceZeroIsAPlainSurfaceWhoseAlbedoAnOverrideSets) {
  ScratchDir dir;
  const fs::path file = WriteSceneWithInstances(
      dir, "[]",
      R"(, "quad_lights": [{"name": "paving", "corner": [0, -1, 0], "edge1": [0, 0, 4], "edge2": [4, 0, 0],
                            "radiance": [0, 0, 0]}],
          "materials": {"paving": {"albedo": [0.3, 0.25, 0.2]}})");
  auto scene = LoadScene(file);
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  EXPECT_TRUE(scene->instances.empty());
  const Material& paving = scene->MaterialOf(uint32_t(scene->triangles.size() - 1));
  EXPECT_EQ(paving.name, "paving");
  EXPECT_FALSE(paving.IsEmissive());
  EXPECT_FLOAT_EQ(paving.albedo.g, 0.25f);
}

// An OBJ of `quads` unit squares in a row (2 triangles each).
std::string RowOfQuads(int quads) {
  std::string obj;
  for (int i = 0; i <= quads; ++i) obj += fmt::format("v {} 0 0\nv {} 0 1\n", i, i);
  for (int i = 0; i < quads; ++i)
    obj += fmt::format("f {} {} {}\nf {} {} {}\n", 2 * i + 1, 2 * i + 2, 2 * i + 4, 2 * i + 1, 2 * i + 4, 2 * i + 3);
  return obj;
}

TEST(SceneInstancesTest, CopiesArePlacedInTheStaticPartWithTheMeshsMaterialsAddedOnce) {
  auto box = LoadScene(CornellBoxObj());
  ASSERT_TRUE(box.ok()) << box.error().message;
  ScratchDir dir;
  const std::string mesh = CornellBoxObj().string();
  // Three copies (one turned a quarter about y) and a movable object after
  // them (a mesh of its own: a movable object may not emit).
  dir.Write("row.obj", RowOfQuads(2));
  const std::string crate = R"(, "objects": {"crate": {"mesh": "row.obj", "transform": {"translate": [0, 5, -30]}}})";
  const fs::path file = WriteSceneWithInstances(
      dir,
      fmt::format(R"([{{"mesh": "{0}", "transform": {{"translate": [10, 0, 0]}}}},
                      {{"mesh": "{0}", "transform": {{"translate": [20, 0, 0]}}}},
                      {{"mesh": "{0}", "transform": {{"translate": [0, 0, 30], "rotate_deg": 90}}}}])",
                  mesh),
      crate);
  auto scene = LoadScene(file);
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  const uint32_t n = uint32_t(box->triangles.size()), nv = uint32_t(box->vertices.size());
  ASSERT_EQ(scene->instances.size(), 3u);
  // The main mesh, three copies, the object.
  EXPECT_EQ(scene->triangles.size(), 4u * n + 4u);
  EXPECT_EQ(scene->staticTriangleCount, 4u * n);
  ASSERT_EQ(scene->objects.size(), 1u);
  EXPECT_EQ(scene->objects[0].firstTriangle, 4u * n);
  EXPECT_EQ(scene->objects[0].firstVertex, 4u * nv);
  // The instanced mesh's materials are added once, however many copies.
  ScratchDir one;
  one.Write("row.obj", RowOfQuads(2));
  auto oneCopy = LoadScene(WriteSceneWithInstances(one, fmt::format(R"([{{"mesh": "{}"}}])", mesh), crate));
  ASSERT_TRUE(oneCopy.ok()) << oneCopy.error().message;
  EXPECT_EQ(scene->materials.size(), oneCopy->materials.size());
  EXPECT_EQ(scene->textures.size(), oneCopy->textures.size());
  const RigidTransform quarter = RigidTransform::FromAxisAngle(Vec3(0, 1, 0), kPi / 2, Vec3(0, 0, 30));
  for (uint32_t k = 0; k < 3; ++k) {
    SCOPED_TRACE(k);
    const StaticInstance& copy = scene->instances[k];
    EXPECT_EQ(copy.firstTriangle, (k + 1) * n);
    EXPECT_EQ(copy.triangleCount, n);
    EXPECT_EQ(copy.firstVertex, (k + 1) * nv);
    EXPECT_EQ(copy.vertexCount, nv);
    EXPECT_EQ(copy.prototype, 0u);
    const RigidTransform expected =
        k == 2 ? quarter : RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.0f, Vec3(10.0f * (k + 1), 0, 0));
    for (uint32_t v = 0; v < nv; ++v) {
      const Vertex& placed = scene->vertices[copy.firstVertex + v];
      EXPECT_NEAR(glm::length(placed.position - expected.ApplyPoint(box->vertices[v].position)), 0.0f, 1e-4f);
      EXPECT_NEAR(glm::dot(placed.normal, expected.ApplyVector(box->vertices[v].normal)), 1.0f, 1e-5f);
    }
    for (uint32_t t = 0; t < n; ++t) {
      const Triangle& placed = scene->triangles[copy.firstTriangle + t];
      EXPECT_EQ(placed.v[0] - copy.firstVertex, box->triangles[t].v[0]);
      EXPECT_EQ(scene->materials[placed.material].name, box->materials[box->triangles[t].material].name);
      EXPECT_EQ(scene->materials[placed.material].emission, box->materials[box->triangles[t].material].emission);
    }
  }
  // The copies' lights light the scene too.
  EXPECT_EQ(scene->emissiveTriangles.size(), 4 * box->emissiveTriangles.size());
  // Bounds reach the farthest copy.
  EXPECT_GE(scene->bounds.max.x, 20.0f);
}

TEST(SceneInstancesTest, MaterialOverridesReachTheCopies) {
  ScratchDir dir;
  const fs::path file = WriteSceneWithInstances(
      dir, fmt::format(R"([{{"mesh": "{}", "transform": {{"translate": [10, 0, 0]}}}}])", CornellBoxObj().string()),
      R"(, "materials": {"light": {"emission": [0, 0, 0]}}, "sun": {"direction": [0, 1, 0], "irradiance": [1, 1, 1]})");
  auto scene = LoadScene(file);
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  EXPECT_TRUE(scene->emissiveTriangles.empty());
}

TEST(SceneInstancesTest, EveryBadInstanceIsAnErrorNamingTheFileAndTheField) {
  const std::string mesh = CornellBoxObj().string();
  struct Case {
    std::string label, instances, problem;
  };
  std::string tooMany = "[";
  for (int i = 0; i <= 4096; ++i) tooMany += fmt::format(R"({}{{"mesh": "{}"}})", i ? "," : "", mesh);
  tooMany += "]";
  const std::vector<Case> cases = {
      {"not an array", R"({"a": 1})", "\"instances\" must be an array"},
      {"not an object", "[1]", "instances[0]: must be an object"},
      {"unknown key", fmt::format(R"([{{"mesh": "{}", "scale": 2}}])", mesh), "instances[0]: unknown key \"scale\""},
      {"no mesh", R"([{"transform": {"translate": [1, 2, 3]}}])", "instances[0]: missing \"mesh\""},
      {"scaled", fmt::format(R"([{{"mesh": "{}", "transform": {{"matrix": [2,0,0,0, 0,2,0,0, 0,0,2,0]}}}}])", mesh),
       "instances[0].transform"},
      {"bad key in transform", fmt::format(R"([{{"mesh": "{}", "transform": {{"move": [1, 2, 3]}}}}])", mesh),
       "instances[0].transform: unknown key \"move\""},
      {"missing mesh file", R"([{"mesh": "nowhere.obj"}])", "instances: "},
      {"too many", tooMany, "instances: 4097 instances; at most 4096"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.label);
    ScratchDir dir;
    const fs::path file = WriteSceneWithInstances(dir, c.instances);
    auto scene = LoadScene(file);
    ASSERT_FALSE(scene.ok());
    EXPECT_NE(scene.error().message.find(file.string()), std::string::npos) << scene.error().message;
    EXPECT_NE(scene.error().message.find(c.problem), std::string::npos) << scene.error().message;
  }
}

TEST(SceneInstancesTest, TooManyTrianglesInAllIsRefusedBeforeAnyCopyIsMade) {
  ScratchDir dir;
  // 4096 copies of 4100 triangles: 16.8 million, past the 16.7 million bound.
  dir.Write("row.obj", RowOfQuads(2050));
  std::string instances = "[";
  for (int i = 0; i < 4096; ++i)
    instances += fmt::format(R"({}{{"mesh": "row.obj", "transform": {{"translate": [0, {}, 0]}}}})", i ? "," : "", i);
  instances += "]";
  const fs::path file = WriteSceneWithInstances(dir, instances);
  auto scene = LoadScene(file);
  ASSERT_FALSE(scene.ok());
  const std::string& message = scene.error().message;
  EXPECT_NE(message.find(file.string()), std::string::npos) << message;
  EXPECT_NE(message.find("instances: 4096 copies of"), std::string::npos) << message;
  EXPECT_NE(message.find("row.obj (4100 triangles each)"), std::string::npos) << message;
  EXPECT_NE(message.find("at most 16777216"), std::string::npos) << message;
}

}  // namespace
}  // namespace penumbra
