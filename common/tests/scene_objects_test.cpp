// Movable objects in scene files (issue 14, docs/scenes.md "Movable objects"):
// "group" objects cut out of the main mesh by node name, "mesh" objects read
// from files of their own, transforms, animations, every error, and the
// repository's scenes that use them.

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "penumbra/common/scene.h"
#include "test_files.h"

namespace penumbra {
namespace {

namespace fs = std::filesystem;
using testing::ExpectNear;
using testing::ScratchDir;
using testing::SharedScene;
using testing::SourceDir;
using testing::TestData;

// Groups (OBJ "g"), in this order: floor (10 x 10 at y = 0, facing up),
// crate (a box x 1.5..2.5, y 0.2..1.2, z 2..4: centre (2, 0.7, 3), 12
// triangles), lamp (a 1 x 1 emitter at y = 3 facing down), empty (no faces),
// shelf (one triangle at y = 1).
constexpr const char* kPartsObj = R"(mtllib parts.mtl
v -5 0 -5
v 5 0 -5
v 5 0 5
v -5 0 5
v 1.5 0.2 2
v 2.5 0.2 2
v 2.5 1.2 2
v 1.5 1.2 2
v 1.5 0.2 4
v 2.5 0.2 4
v 2.5 1.2 4
v 1.5 1.2 4
v -0.5 3 -0.5
v 0.5 3 -0.5
v 0.5 3 0.5
v -0.5 3 0.5
v -2 1 -2
v -1 1 -2
v -2 1 -1
g floor
usemtl floor
f 1 4 3 2
g crate
usemtl crate
f 5 8 7 6
f 9 10 11 12
f 5 9 12 8
f 6 7 11 10
f 5 6 10 9
f 8 12 11 7
g lamp
usemtl lamp
f 13 14 15 16
g empty
g shelf
usemtl shelf
f 17 19 18
)";
constexpr const char* kPartsMtl = "newmtl floor\nKd 0.8 0.8 0.8\nnewmtl crate\nKd 0.5 0.4 0.3\n"
                                  "newmtl lamp\nKd 0 0 0\nKe 5 5 5\nnewmtl shelf\nKd 0.3 0.3 0.3\n";

// A cube 0.5 wide centred on its origin, material "paint".
constexpr const char* kCubeObj = R"(mtllib cube.mtl
v -0.25 -0.25 -0.25
v 0.25 -0.25 -0.25
v 0.25 0.25 -0.25
v -0.25 0.25 -0.25
v -0.25 -0.25 0.25
v 0.25 -0.25 0.25
v 0.25 0.25 0.25
v -0.25 0.25 0.25
usemtl paint
f 1 4 3 2
f 5 6 7 8
f 1 5 8 4
f 2 3 7 6
f 1 2 6 5
f 4 8 7 3
)";
constexpr const char* kCubeMtl = "newmtl paint\nKd 0.2 0.6 0.9\n";

// Writes parts.obj/.mtl and cube.obj/.mtl beside a scene file whose
// "objects" member is `objects`; returns the scene file.
fs::path WriteScene(const ScratchDir& dir, const std::string& objects) {
  dir.Write("parts.obj", kPartsObj);
  dir.Write("parts.mtl", kPartsMtl);
  dir.Write("cube.obj", kCubeObj);
  dir.Write("cube.mtl", kCubeMtl);
  return dir.Write("scene.json", R"({"mesh": "parts.obj", "objects": )" + objects + "}");
}

using WorldTriangle = std::array<Vec3, 3>;

bool WorldTriangleLess(const WorldTriangle& a, const WorldTriangle& b) {
  for (int c = 0; c < 3; ++c)
    for (int i = 0; i < 3; ++i)
      if (a[c][i] != b[c][i]) return a[c][i] < b[c][i];
  return false;
}

// The world corners of triangles [first, first + count) at `pose`, each
// rotated to start at its smallest corner (lexicographically) and the list
// sorted, so that two scenes numbering the same surfaces differently compare
// equal.
std::vector<WorldTriangle> WorldTriangles(const Scene& scene, const ScenePose& pose, uint32_t first, uint32_t count) {
  std::vector<WorldTriangle> out;
  const auto less = [](const Vec3& a, const Vec3& b) {
    return a.x != b.x ? a.x < b.x : a.y != b.y ? a.y < b.y : a.z < b.z;
  };
  for (uint32_t t = first; t < first + count; ++t) {
    WorldTriangle w{WorldPointAt(scene, pose, t, 0, 0), WorldPointAt(scene, pose, t, 1, 0),
                    WorldPointAt(scene, pose, t, 0, 1)};
    // Round away float noise from the object-space round trip before ordering.
    for (Vec3& p : w) p = glm::round(p * 1e4f) / 1e4f;
    const auto smallest = std::min_element(w.begin(), w.end(), less);
    std::rotate(w.begin(), smallest, w.end());
    out.push_back(w);
  }
  std::sort(out.begin(), out.end(), WorldTriangleLess);
  return out;
}

// WorldTriangles of the triangles of one material among [first, first + count).
std::vector<WorldTriangle> TrianglesOfMaterial(const Scene& scene, const ScenePose& pose, std::string_view material,
                                               uint32_t first, uint32_t count) {
  std::vector<WorldTriangle> all;
  for (uint32_t t = first; t < first + count; ++t)
    if (scene.MaterialOf(t).name == material) all.push_back(WorldTriangles(scene, pose, t, 1)[0]);
  std::sort(all.begin(), all.end(), WorldTriangleLess);
  return all;
}

// --- Group objects ------------------------------------------------------------

TEST(SceneObjectsTest, GroupBecomesAnObjectCentredOnItsBoundsAndStaysWhereTheMeshHasIt) {
  ScratchDir dir;
  auto moving = LoadScene(WriteScene(dir, R"({"crate": {"group": "crate"}})"));
  ASSERT_TRUE(moving.ok()) << moving.error().message;
  auto still = LoadScene(dir / "parts.obj");
  ASSERT_TRUE(still.ok()) << still.error().message;
  ASSERT_TRUE(still->objects.empty());

  ASSERT_EQ(moving->objects.size(), 1u);
  const MovableObject& crate = moving->objects[0];
  EXPECT_EQ(crate.name, "crate");
  EXPECT_EQ(moving->FindObject("crate"), 0u);
  // The ranges: the static part first, then the crate's 12 triangles and 8
  // corners (a box's corners split at its right angles: 3 vertices each).
  EXPECT_EQ(crate.firstTriangle, moving->staticTriangleCount);
  EXPECT_EQ(crate.triangleCount, 12u);
  EXPECT_EQ(crate.firstTriangle + crate.triangleCount, moving->triangles.size());
  EXPECT_EQ(crate.firstVertex, moving->staticVertexCount);
  EXPECT_EQ(crate.firstVertex + crate.vertexCount, moving->vertices.size());
  EXPECT_EQ(crate.vertexCount, 24u);
  EXPECT_EQ(moving->staticTriangleCount, still->triangles.size() - 12);
  for (uint32_t t = crate.firstTriangle; t < crate.firstTriangle + crate.triangleCount; ++t)
    EXPECT_EQ(moving->MaterialOf(t).name, "crate");

  // Object space is centred on the group's bounding box: (2, 0.7, 3).
  ExpectNear(crate.objectBounds.min, Vec3(-0.5f, -0.5f, -1.0f), 1e-5f, "object-space min");
  ExpectNear(crate.objectBounds.max, Vec3(0.5f, 0.5f, 1.0f), 1e-5f, "object-space max");
  EXPECT_EQ(crate.objectToWorld.rotation, glm::mat3(1.0f));
  ExpectNear(crate.objectToWorld.translation, Vec3(2.0f, 0.7f, 3.0f), 1e-6f, "placement");
  EXPECT_FALSE(crate.animation.has_value());

  // At the initial pose every triangle is where the static scene has it.
  const ScenePose pose = ScenePose::Initial(*moving);
  const ScenePose stillPose = ScenePose::Initial(*still);
  EXPECT_EQ(WorldTriangles(*moving, pose, 0, uint32_t(moving->triangles.size())),
            WorldTriangles(*still, stillPose, 0, uint32_t(still->triangles.size())));
  EXPECT_EQ(WorldTriangles(*moving, pose, crate.firstTriangle, crate.triangleCount),
            TrianglesOfMaterial(*still, stillPose, "crate", 0, uint32_t(still->triangles.size())));
  ExpectNear(WorldBounds(*moving, pose, 0).min, Vec3(1.5f, 0.2f, 2.0f), 1e-5f, "world min");
  ExpectNear(WorldBounds(*moving, pose, 0).max, Vec3(2.5f, 1.2f, 4.0f), 1e-5f, "world max");
  ExpectNear(moving->bounds.min, still->bounds.min, 1e-5f);
  ExpectNear(moving->bounds.max, still->bounds.max, 1e-5f);
  EXPECT_EQ(moving->emissiveTriangles.size(), 2u) << "the lamp stays a static light";
  EXPECT_NE(moving->identity, still->identity);
}

TEST(SceneObjectsTest, GroupListPivotAndTransformRotateTheGroupAboutThePivot) {
  ScratchDir dir;
  // Crate and shelf together, pivot on the floor under the crate's centre,
  // turned 90 degrees about +y and lifted by 1.
  auto scene = LoadScene(WriteScene(dir, R"({"stack": {"group": ["crate", "shelf"], "pivot": [2, 0, 3],
      "transform": {"rotate_deg": 90, "axis": [0, 2, 0], "translate": [0, 1, 0]}}})"));
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  ASSERT_EQ(scene->objects.size(), 1u);
  const MovableObject& stack = scene->objects[0];
  EXPECT_EQ(stack.triangleCount, 13u);
  // objectToWorld = translate(pivot) * (translate(0, 1, 0) * rotate 90).
  const RigidTransform expected =
      RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.5f * kPi, Vec3(2.0f, 1.0f, 3.0f));
  for (int c = 0; c < 3; ++c) ExpectNear(stack.objectToWorld.rotation[c], expected.rotation[c], 1e-6f, "rotation");
  ExpectNear(stack.objectToWorld.translation, expected.translation, 1e-6f, "translation");
  // Rotating +90 about +y takes (x, z) to (z, -x) about the pivot: the
  // crate's corner (2.5, 0.2, 4) -> relative (0.5, 0.2, 1) -> (1, 0.2, -0.5)
  // -> world (3, 1.2, 2.5). So the crate spans x 1..3, z 2.5..3.5, lifted.
  const ScenePose pose = ScenePose::Initial(*scene);
  Bounds3 crate;
  for (uint32_t t = stack.firstTriangle; t < stack.firstTriangle + stack.triangleCount; ++t)
    if (scene->MaterialOf(t).name == "crate")
      for (const auto& [b1, b2] : {std::pair{0.0f, 0.0f}, {1.0f, 0.0f}, {0.0f, 1.0f}})
        crate.Extend(WorldPointAt(*scene, pose, t, b1, b2));
  ExpectNear(crate.min, Vec3(1.0f, 1.2f, 2.5f), 1e-5f, "turned crate min");
  ExpectNear(crate.max, Vec3(3.0f, 2.2f, 3.5f), 1e-5f, "turned crate max");
  // The shelf's corner (-2, 1, -2): relative (-4, 1, -5) -> (-5, 1, 4) -> world (-3, 2, 7).
  bool shelfCornerFound = false;
  for (uint32_t t = stack.firstTriangle; t < stack.firstTriangle + stack.triangleCount; ++t)
    for (const auto& [b1, b2] : {std::pair{0.0f, 0.0f}, {1.0f, 0.0f}, {0.0f, 1.0f}})
      shelfCornerFound |= glm::length(WorldPointAt(*scene, pose, t, b1, b2) - Vec3(-3.0f, 2.0f, 7.0f)) < 1e-4f;
  EXPECT_TRUE(shelfCornerFound);
}

TEST(SceneObjectsTest, GltfNodeGroupTakesItsMeshWithTheNodeTransformsApplied) {
  ScratchDir dir;
  // two_materials.gltf: root (translation 0 1 0) > quad (scale 2): the unit
  // square in z = 0 -> world (0, 1, 0)..(2, 3, 0); lamp stays static.
  const fs::path scene = dir.Write("scene.json", R"({"mesh": ")" + TestData("two_materials.gltf").string() +
                                                     R"(", "objects": {"panel": {"group": "quad"}}})");
  auto loaded = LoadScene(scene);
  ASSERT_TRUE(loaded.ok()) << loaded.error().message;
  ASSERT_EQ(loaded->objects.size(), 1u);
  const MovableObject& panel = loaded->objects[0];
  EXPECT_EQ(panel.triangleCount, 2u);
  ExpectNear(panel.objectBounds.min, Vec3(-1.0f, -1.0f, 0.0f), 1e-6f);
  ExpectNear(panel.objectBounds.max, Vec3(1.0f, 1.0f, 0.0f), 1e-6f);
  const Bounds3 world = WorldBounds(*loaded, ScenePose::Initial(*loaded), 0);
  ExpectNear(world.min, Vec3(0.0f, 1.0f, 0.0f), 1e-6f);
  ExpectNear(world.max, Vec3(2.0f, 3.0f, 0.0f), 1e-6f);
  EXPECT_EQ(loaded->MaterialOf(panel.firstTriangle).name, "textured");
  EXPECT_EQ(loaded->emissiveTriangles.size(), 1u);
}

TEST(SceneObjectsTest, GltfGroupsNestAndANodeInsideAnotherObjectsNodeIsAnError) {
  ScratchDir dir;
  auto load = [&](const std::string& objects) {
    return LoadScene(dir.Write("scene.json", R"({"mesh": ")" + TestData("two_materials.gltf").string() +
                                                 R"(", "objects": )" + objects + "}"));
  };
  // "root" holds both meshes: nothing would stay static.
  auto whole = load(R"({"all": {"group": "root"}})");
  ASSERT_FALSE(whole.ok());
  EXPECT_NE(whole.error().message.find("nothing would stay static"), std::string::npos) << whole.error().message;
  auto nested = load(R"({"all": {"group": "root"}, "panel": {"group": "quad"}})");
  ASSERT_FALSE(nested.ok());
  EXPECT_NE(nested.error().message.find("objects.panel: node \"quad\" is inside a node of objects.all"),
            std::string::npos)
      << nested.error().message;
}

// The Cornell box OBJ writes each box's "g" line after its faces, so assimp
// files them under the group before (docs/scenes.md, "Finding names").
TEST(SceneObjectsTest, CornellBoxGroupsAreWhereAssimpPutsThem) {
  ScratchDir dir;
  const fs::path obj = SourceDir() / "scenes/cornell-box/CornellBox-Original.obj";
  auto load = [&](const std::string& objects) {
    return LoadScene(dir.Write("scene.json", R"({"mesh": ")" + obj.string() + R"(", "objects": )" + objects + "}"));
  };
  auto materialsOf = [](const Scene& scene, const MovableObject& o) {
    std::vector<std::string> names;
    for (uint32_t t = o.firstTriangle; t < o.firstTriangle + o.triangleCount; ++t)
      if (std::find(names.begin(), names.end(), scene.MaterialOf(t).name) == names.end())
        names.push_back(scene.MaterialOf(t).name);
    std::sort(names.begin(), names.end());
    return names;
  };
  auto scene = load(R"({"a": {"group": "shortBox"}, "b": {"group": "leftWall"}})");
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  EXPECT_EQ(materialsOf(*scene, scene->objects[0]), std::vector<std::string>{"tallBox"});
  EXPECT_EQ(materialsOf(*scene, scene->objects[1]), (std::vector<std::string>{"leftWall", "shortBox"}));
  auto tall = load(R"({"a": {"group": "tallBox"}})");
  ASSERT_FALSE(tall.ok());
  EXPECT_NE(tall.error().message.find("the group \"tallBox\" has no triangles"), std::string::npos)
      << tall.error().message;
}

// --- Mesh-file objects ----------------------------------------------------------

TEST(SceneObjectsTest, MeshFileObjectKeepsItsFileCoordinatesAndItsMaterialsJoinTheScene) {
  ScratchDir dir;
  // A rotation of 90 degrees about +z (x -> y, y -> -x) and a translation,
  // as a row-major 3x4 matrix; then a group object, which comes first.
  auto scene = LoadScene(WriteScene(dir, R"({"cube": {"mesh": "cube.obj",
      "transform": {"matrix": [0, -1, 0, 1.5,  1, 0, 0, 0.75,  0, 0, 1, -2]}},
      "crate": {"group": "crate"}})"));
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  ASSERT_EQ(scene->objects.size(), 2u);
  EXPECT_EQ(scene->objects[0].name, "crate") << "group objects first";
  const MovableObject& cube = scene->objects[1];
  EXPECT_EQ(cube.name, "cube");
  EXPECT_EQ(cube.triangleCount, 12u);
  EXPECT_EQ(cube.firstTriangle, scene->objects[0].firstTriangle + scene->objects[0].triangleCount);
  ExpectNear(cube.objectBounds.min, Vec3(-0.25f), 1e-6f, "object space = the file's coordinates");
  ExpectNear(cube.objectBounds.max, Vec3(0.25f), 1e-6f);
  ExpectNear(cube.objectToWorld.ApplyPoint(Vec3(1, 0, 0)), Vec3(1.5f, 1.75f, -2.0f), 1e-6f);
  ExpectNear(cube.objectToWorld.ApplyPoint(Vec3(0, 1, 0)), Vec3(0.5f, 0.75f, -2.0f), 1e-6f);
  for (uint32_t t = cube.firstTriangle; t < cube.firstTriangle + cube.triangleCount; ++t)
    EXPECT_EQ(scene->MaterialOf(t).name, "paint");
  ExpectNear(scene->MaterialOf(cube.firstTriangle).albedo, Vec3(0.2f, 0.6f, 0.9f), 1e-6f);
  // No transform: the identity.
  auto plain = LoadScene(WriteScene(dir, R"({"cube": {"mesh": "cube.obj"}})"));
  ASSERT_TRUE(plain.ok()) << plain.error().message;
  EXPECT_EQ(plain->objects[0].objectToWorld, RigidTransform::Identity());
}

// --- Animations -------------------------------------------------------------------

TEST(SceneObjectsTest, AnimationKeyframesAreParsedAndAGroupsKeysAreRelativeToItsHomeFrame) {
  ScratchDir dir;
  auto scene = LoadScene(WriteScene(dir, R"({
      "cube": {"mesh": "cube.obj", "animation": {"loop": false, "keyframes": [
          {"t": 0, "translate": [0, 1, 0]},
          {"t": 2, "translate": [2, 1, 0], "rotate_deg": 90},
          {"t": 2.5, "matrix": [1, 0, 0, 0,  0, 1, 0, 4,  0, 0, 1, 0]}]}},
      "crate": {"group": "crate", "animation": {"keyframes": [{"t": 0}, {"t": 1, "translate": [0, 0, -1]}]}}})"));
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  const MovableObject& crate = scene->objects[0];
  const MovableObject& cube = scene->objects[1];

  ASSERT_TRUE(cube.animation.has_value());
  const ObjectAnimation& a = *cube.animation;
  EXPECT_FALSE(a.loop);
  ASSERT_EQ(a.keys.size(), 3u);
  EXPECT_EQ(a.keys[1].timeS, 2.0f);
  EXPECT_DOUBLE_EQ(a.DurationS(), 2.5);
  ExpectNear(cube.objectToWorld.translation, Vec3(0, 1, 0), 0.0f, "placed at the first key");
  ExpectNear(a.At(1.0).translation, Vec3(1, 1, 0), 1e-6f, "halfway to the second key");
  ExpectNear(a.At(1.0).ApplyVector(Vec3(1, 0, 0)), Vec3(std::cos(kPi / 4), 0, -std::sin(kPi / 4)), 1e-5f,
             "and turned halfway, 45 degrees about +y");
  ExpectNear(a.At(100.0).translation, Vec3(0, 4, 0), 0.0f, "once: held at the last key");

  ASSERT_TRUE(crate.animation.has_value());
  EXPECT_TRUE(crate.animation->loop) << "loop is the default";
  // Keys relative to translate(centre of the crate) = (2, 0.7, 3).
  ExpectNear(crate.objectToWorld.translation, Vec3(2.0f, 0.7f, 3.0f), 1e-6f);
  ExpectNear(crate.animation->keys[0].objectToWorld.translation, Vec3(2.0f, 0.7f, 3.0f), 1e-6f);
  ExpectNear(crate.animation->keys[1].objectToWorld.translation, Vec3(2.0f, 0.7f, 2.0f), 1e-6f);
  ExpectNear(crate.animation->At(1.5).translation, Vec3(2.0f, 0.7f, 2.5f), 1e-6f, "looped");
}

// --- Errors ----------------------------------------------------------------------

struct BadObjects {
  const char* label;
  const char* objects;  // the "objects" member
  const char* problem;  // a fragment the message must contain
};

const BadObjects kBadObjects[] = {
    {"NotAnObject", R"([1])", "\"objects\" must be an object"},
    {"ObjectNotAnObject", R"({"a": 3})", "objects.a: must be an object"},
    {"UnknownKey", R"({"a": {"group": "crate", "pivt": [0, 0, 0]}})", "objects.a: unknown key \"pivt\""},
    {"NeitherGroupNorMesh", R"({"a": {"transform": {}}})", "objects.a: give either \"group\" or \"mesh\""},
    {"BothGroupAndMesh", R"({"a": {"group": "crate", "mesh": "cube.obj"}})", "give either \"group\" or \"mesh\""},
    {"EmptyGroupName", R"({"a": {"group": ""}})", "objects.a: \"group\" must be a non-empty string"},
    {"GroupListWithNumber", R"({"a": {"group": ["crate", 3]}})", "objects.a: \"group\" must be"},
    {"UnknownGroup", R"({"a": {"group": "crates"}})",
     "objects.a: no node (OBJ o/g group, glTF node) is called \"crates\"; the file has: \"parts.obj\", \"floor\", "
     "\"crate\", \"lamp\", \"empty\", \"shelf\""},
    {"GroupWithoutTriangles", R"({"a": {"group": "empty"}})", "objects.a: the group \"empty\" has no triangles"},
    {"GroupNamedTwice", R"({"a": {"group": "crate"}, "b": {"group": ["shelf", "crate"]}})",
     "objects.a and objects.b both name the group \"crate\""},
    {"GroupsTakeEverything", R"({"a": {"group": ["floor", "crate", "lamp", "shelf"]}})", "nothing would stay static"},
    {"WholeFileByRootNode", R"({"a": {"group": "parts.obj"}})", "nothing would stay static"},
    {"EmissiveGroup", R"({"a": {"group": "lamp"}})",
     "movable object 'a' has an emissive material ('lamp'); moving lights are not supported"},
    {"MissingMeshFile", R"({"a": {"mesh": "absent.obj"}})", "objects.a: "},
    {"MeshWithPivot", R"({"a": {"mesh": "cube.obj", "pivot": [0, 0, 0]}})", "\"pivot\" is for \"group\" objects"},
    {"BadPivot", R"({"a": {"group": "crate", "pivot": [0, 0]}})", "objects.a: \"pivot\" must be an array of 3"},
    {"TransformNotAnObject", R"({"a": {"group": "crate", "transform": [1, 0, 0]}})",
     "objects.a: \"transform\" must be an object"},
    {"TransformUnknownKey", R"({"a": {"group": "crate", "transform": {"rotate": 30}}})",
     "objects.a.transform: unknown key \"rotate\""},
    {"TransformBadTranslate", R"({"a": {"group": "crate", "transform": {"translate": [0, "1", 0]}}})",
     "objects.a.transform: \"translate\" must be an array of 3 finite numbers"},
    {"TransformOverflow", R"({"a": {"group": "crate", "transform": {"translate": [0, 1e39, 0]}}})",
     "objects.a.transform: \"translate\" must be an array of 3 finite numbers"},
    {"TransformFarAway", R"({"a": {"group": "crate", "transform": {"translate": [0, 2e7, 0]}}})",
     "objects.a.transform: translation"},
    {"PivotAndTranslateTooFar",
     R"({"a": {"group": "crate", "pivot": [9e6, 0, 0], "transform": {"translate": [9e6, 0, 0]}}})",
     "objects.a: translation (18000000, 0, 0) is beyond 10000000"},
    {"AxisWithoutAngle", R"({"a": {"group": "crate", "transform": {"axis": [1, 0, 0]}}})",
     "objects.a.transform: \"axis\" without \"rotate_deg\""},
    {"ZeroAxis", R"({"a": {"group": "crate", "transform": {"rotate_deg": 10, "axis": [0, 0, 0]}}})",
     "objects.a.transform: \"axis\" must not be zero"},
    {"AngleTooLarge", R"({"a": {"group": "crate", "transform": {"rotate_deg": 1e6}}})",
     "objects.a.transform: \"rotate_deg\" must be a number in"},
    {"MatrixWithTranslate", R"({"a": {"group": "crate", "transform": {"matrix": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0],
        "translate": [1, 0, 0]}}})",
     "objects.a.transform: give either \"matrix\" or \"translate\""},
    {"MatrixTooShort", R"({"a": {"group": "crate", "transform": {"matrix": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]}}})",
     "objects.a.transform: \"matrix\" must be an array of 12 numbers"},
    {"MatrixScaled",
     R"({"a": {"group": "crate", "transform": {"matrix": [1.1, 0, 0, 0, 0, 1.1, 0, 0, 0, 0, 1.1, 0]}}})",
     "objects.a.transform: the 3x3 part is not a rotation"},
    {"MatrixMirrored", R"({"a": {"mesh": "cube.obj", "transform": {"matrix": [-1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0]}}})",
     "objects.a.transform: the 3x3 part is not a rotation"},
    {"MatrixSheared", R"({"a": {"mesh": "cube.obj", "transform": {"matrix": [1, 0.5, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0]}}})",
     "only rigid moves are allowed"},
    {"MatrixCollapsed", R"({"a": {"mesh": "cube.obj", "transform": {"matrix": [0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]}}})",
     "not a rotation"},
    {"MatrixInfinite",
     R"({"a": {"mesh": "cube.obj", "transform": {"matrix": [1, 0, 0, 1e39, 0, 1, 0, 0, 0, 0, 1, 0]}}})",
     "objects.a.transform: transform entry 3 is not finite"},
    {"MatrixString", R"({"a": {"mesh": "cube.obj", "transform": {"matrix": [1, 0, 0, "x", 0, 1, 0, 0, 0, 0, 1, 0]}}})",
     "objects.a.transform: \"matrix\" entry 3 is not a number"},
    {"TransformAndAnimation",
     R"({"a": {"group": "crate", "transform": {}, "animation": {"keyframes": [{"t": 0}, {"t": 1}]}}})",
     "objects.a: give either \"transform\" or \"animation\""},
    {"AnimationNotAnObject", R"({"a": {"group": "crate", "animation": []}})", "objects.a.animation: must be an object"},
    {"AnimationUnknownKey", R"({"a": {"group": "crate", "animation": {"loops": true, "keyframes": []}}})",
     "objects.a.animation: unknown key \"loops\""},
    {"AnimationLoopNotBool", R"({"a": {"group": "crate", "animation": {"loop": 1, "keyframes": []}}})",
     "objects.a.animation: \"loop\" must be true or false"},
    {"AnimationWithoutKeyframes", R"({"a": {"group": "crate", "animation": {"loop": true}}})",
     "objects.a.animation: missing \"keyframes\""},
    {"AnimationOneKeyframe", R"({"a": {"group": "crate", "animation": {"keyframes": [{"t": 0}]}}})",
     "objects.a.animation: \"keyframes\" must be an array of 2 to 10000 keyframes"},
    {"KeyframeNotAnObject", R"({"a": {"group": "crate", "animation": {"keyframes": [{"t": 0}, 1]}}})",
     "objects.a.animation.keyframes[1]: must be an object"},
    {"KeyframeWithoutTime",
     R"({"a": {"group": "crate", "animation": {"keyframes": [{"t": 0}, {"translate": [0, 1, 0]}]}}})",
     "objects.a.animation.keyframes[1]: missing \"t\""},
    {"KeyframeTypo",
     R"({"a": {"group": "crate", "animation": {"keyframes": [{"t": 0}, {"t": 1, "translat": [0, 1, 0]}]}}})",
     "objects.a.animation.keyframes[1]: unknown key \"translat\""},
    {"FirstKeyframeLate", R"({"a": {"group": "crate", "animation": {"keyframes": [{"t": 1}, {"t": 2}]}}})",
     "objects.a.animation.keyframes[0]: the first keyframe must be at \"t\": 0"},
    {"KeyframesOutOfOrder",
     R"({"a": {"group": "crate", "animation": {"keyframes": [{"t": 0}, {"t": 2}, {"t": 1}]}}})",
     "objects.a.animation.keyframes[2]: \"t\" (1) must be after the previous keyframe's (2)"},
    {"KeyframesAtTheSameTime", R"({"a": {"group": "crate", "animation": {"keyframes": [{"t": 0}, {"t": 0}]}}})",
     "objects.a.animation.keyframes[1]: \"t\" (0) must be after"},
    {"KeyframeNegativeTime", R"({"a": {"group": "crate", "animation": {"keyframes": [{"t": 0}, {"t": -1}]}}})",
     "objects.a.animation.keyframes[1]: \"t\" must be a number in"},
    {"KeyframeNotRigid",
     R"({"a": {"group": "crate", "animation": {"keyframes": [{"t": 0},
        {"t": 1, "matrix": [2, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0]}]}}})",
     "objects.a.animation.keyframes[1]: the 3x3 part is not a rotation"},
    {"EmptyName", R"({"": {"group": "crate"}})", "objects: an object's name must have 1 to 128 bytes"},
    {"NameWithNewline", R"({"a\nb": {"group": "crate"}})", "no control characters"},
    {"GroupWithNewline", R"({"a": {"group": "cr\nate"}})", "objects.a: \"group\" must be a non-empty string"},
};

// One test for the whole table (each process start costs ~0.3 s of
// OpenImageIO set-up).
TEST(SceneObjectsTest, EveryBadObjectIsAnErrorNamingTheFileAndTheField) {
  for (const BadObjects& input : kBadObjects) {
    SCOPED_TRACE(input.label);
    ScratchDir dir;
    const fs::path file = WriteScene(dir, input.objects);
    auto scene = LoadScene(file);
    ASSERT_FALSE(scene.ok()) << input.objects << " loaded";
    const std::string& message = scene.error().message;
    EXPECT_EQ(message.rfind(file.string(), 0), 0u) << "starts with the scene file: " << message;
    EXPECT_NE(message.find(input.problem), std::string::npos) << message;
    EXPECT_EQ(message.find('\n'), std::string::npos) << "one line: " << message;
  }
}

// Every value under "objects" of a file using every key, replaced in turn by
// values of other types and out of range: each load succeeds or fails with
// one line that names the file and is the parser's own message -- never an
// exception's text (a type nobody checked), a crash or a hang.
TEST(SceneObjectsTest, AnyValueOfAnyTypeUnderObjectsLoadsOrIsRefusedCleanly) {
  ScratchDir dir;
  const nlohmann::json base = nlohmann::json::parse(R"({"mesh": "parts.obj", "objects": {
      "stack": {"group": ["crate", "shelf"], "pivot": [2, 0, 3],
                "animation": {"loop": false, "keyframes": [
                    {"t": 0, "translate": [0, 1, 0], "rotate_deg": 10, "axis": [0, 1, 0]},
                    {"t": 1, "matrix": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0]}]}},
      "cube": {"mesh": "cube.obj", "transform": {"translate": [1, 2, 3], "rotate_deg": 45, "axis": [1, 0, 0]}}}})");
  const fs::path file = WriteScene(dir, base["objects"].dump());
  ASSERT_TRUE(LoadScene(file).ok()) << "the unchanged file loads";
  std::vector<nlohmann::json::json_pointer> places;
  std::vector<nlohmann::json::json_pointer> pending{nlohmann::json::json_pointer("/objects")};
  while (!pending.empty()) {
    const auto at = pending.back();
    pending.pop_back();
    places.push_back(at);
    const nlohmann::json& value = base.at(at);
    if (value.is_object())
      for (const auto& item : value.items()) pending.push_back(at / item.key());
    if (value.is_array())
      for (size_t i = 0; i < value.size(); ++i) pending.push_back(at / i);
  }
  // Few, so that few variants get as far as reading the meshes (~0.1 s each).
  const nlohmann::json replacements[] = {nullptr, "x", 1e30, nlohmann::json::object(),
                                         nlohmann::json::array({1, 2, 3})};
  size_t loaded = 0, refused = 0;
  for (const auto& at : places) {
    for (const nlohmann::json& replacement : replacements) {
      nlohmann::json changed = base;
      changed[at] = replacement;
      const std::string text = changed.dump();
      dir.Write("scene.json", text);
      auto scene = LoadScene(file);
      if (scene.ok()) {
        ++loaded;
        continue;
      }
      ++refused;
      const std::string& message = scene.error().message;
      EXPECT_EQ(message.rfind(file.string(), 0), 0u) << text << "\n" << message;
      EXPECT_EQ(message.find('\n'), std::string::npos) << text << "\n" << message;
      EXPECT_EQ(message.find("cannot load"), std::string::npos) << "an exception escaped: " << text << "\n" << message;
      EXPECT_EQ(message.find("json.exception"), std::string::npos) << text << "\n" << message;
    }
  }
  EXPECT_GT(places.size(), 40u);
  EXPECT_GT(refused, loaded) << "most replacements are wrong";
  EXPECT_GT(loaded, 0u) << "some are harmless (an axis of [1, 2, 3])";
}

TEST(SceneObjectsTest, ObjectCountsAreBounded) {
  ScratchDir dir;
  std::string many = "{";
  for (int i = 0; i <= 256; ++i) many += fmt::format("{}\"o{}\": {{\"mesh\": \"cube.obj\"}}", i ? ", " : "", i);
  many += "}";
  auto scene = LoadScene(WriteScene(dir, many));
  ASSERT_FALSE(scene.ok());
  EXPECT_NE(scene.error().message.find("objects: 257 objects; at most 256 may move"), std::string::npos)
      << scene.error().message;

  std::string keys = R"({"a": {"group": "crate", "animation": {"keyframes": [)";
  for (int i = 0; i <= 10000; ++i) keys += fmt::format("{}{{\"t\": {}}}", i ? ", " : "", i);
  keys += "]}}}";
  scene = LoadScene(WriteScene(dir, keys));
  ASSERT_FALSE(scene.ok());
  EXPECT_NE(scene.error().message.find("2 to 10000 keyframes"), std::string::npos) << scene.error().message;

  const std::string longName(129, 'n');
  scene = LoadScene(WriteScene(dir, R"({")" + longName + R"(": {"group": "crate"}})"));
  ASSERT_FALSE(scene.ok());
  EXPECT_NE(scene.error().message.find("1 to 128 bytes"), std::string::npos) << scene.error().message;
}

// --- The repository's scenes with movable objects -----------------------------------

// The nearest triangle a world-space segment crosses at the initial pose, if any
// (brute force: the Cornell box has 48 triangles).
std::optional<uint32_t> FirstHit(const Scene& scene, const Vec3& from, const Vec3& to) {
  const ScenePose pose = ScenePose::Initial(scene);
  const Vec3 direction = to - from;
  std::optional<uint32_t> nearest;
  float best = 1.0f - 1e-4f;
  for (uint32_t t = 0; t < scene.triangles.size(); ++t) {
    const Vec3 p0 = WorldPointAt(scene, pose, t, 0, 0);
    const Vec3 e1 = WorldPointAt(scene, pose, t, 1, 0) - p0, e2 = WorldPointAt(scene, pose, t, 0, 1) - p0;
    const Vec3 p = glm::cross(direction, e2);
    const float det = glm::dot(e1, p);
    if (std::abs(det) < 1e-12f) continue;
    const Vec3 s = from - p0;
    const float u = glm::dot(s, p) / det;
    const Vec3 q = glm::cross(s, e1);
    const float v = glm::dot(direction, q) / det;
    const float along = glm::dot(e2, q) / det;
    if (u >= 0.0f && v >= 0.0f && u + v <= 1.0f && along > 1e-4f && along < best) {
      best = along;
      nearest = t;
    }
  }
  return nearest;
}

TEST(RepositoryObjectScenesTest, CornellBoxFloatingBoxHangsAboveTheFloorAndShadowsItFromTheLamp) {
  auto scene = LoadScene(SourceDir() / "scenes/cornell-box-floating.json");
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  auto plain = LoadScene(SourceDir() / "scenes/cornell-box.json");
  ASSERT_TRUE(plain.ok()) << plain.error().message;
  EXPECT_EQ(scene->name, "cornell-box-floating");
  ASSERT_EQ(scene->objects.size(), 1u);
  const MovableObject& box = scene->objects[0];
  EXPECT_EQ(box.name, "box");
  EXPECT_EQ(box.triangleCount, 12u);
  EXPECT_FALSE(box.animation.has_value()) << "the user drags it";
  EXPECT_EQ(scene->staticTriangleCount, plain->triangles.size()) << "the Cornell box itself stays static";
  EXPECT_EQ(scene->emissiveTriangles, plain->emissiveTriangles);
  ASSERT_EQ(scene->cameras.size(), plain->cameras.size());
  for (size_t i = 0; i < scene->cameras.size(); ++i) EXPECT_EQ(scene->cameras[i].name, plain->cameras[i].name);
  EXPECT_EQ(scene->paths.size(), plain->paths.size());

  // Inside the box (x -1..1, z -1..1), clear of the floor (y = 0) and the
  // lamp (y = 1.98), and clear of the short box (top 0.6, x > -0.05) and the
  // tall box (z < 0.09 near x = -0.5).
  const Bounds3 world = WorldBounds(*scene, ScenePose::Initial(*scene), 0);
  EXPECT_GT(world.min.y, 0.25f);
  EXPECT_LT(world.max.y, 1.5f);
  EXPECT_GT(world.min.x, -0.95f);
  EXPECT_LT(world.max.x, -0.1f);
  EXPECT_GT(world.min.z, 0.15f);
  EXPECT_LT(world.max.z, 0.95f);
  ExpectNear(world.Diagonal(), Vec3(0.35f * std::sqrt(2.0f) * std::cos(kPi / 12), 0.35f,
                                    0.35f * std::sqrt(2.0f) * std::cos(kPi / 12)),
             1e-4f, "a 0.35 cube turned 30 degrees");

  // The lamp's centre shines through the box onto the floor: that floor
  // point is in the box's shadow, and the front camera sees it.
  const Vec3 lamp = 0.5f * (scene->PointAt(scene->emissiveTriangles[0], 0, 0) +
                            scene->PointAt(scene->emissiveTriangles[0], 1, 0));  // on the lamp's diagonal
  const Vec3 centre = world.Center();
  const Vec3 floorPoint = lamp + (lamp.y / (lamp.y - centre.y)) * (centre - lamp);
  ASSERT_NEAR(floorPoint.y, 0.0f, 1e-4f);
  EXPECT_GT(floorPoint.x, -0.95f);
  EXPECT_LT(floorPoint.z, 0.95f);
  const auto blocker = FirstHit(*scene, floorPoint + Vec3(0, 1e-3f, 0), lamp);
  ASSERT_TRUE(blocker.has_value());
  EXPECT_EQ(scene->ObjectOfTriangle(*blocker), 0u) << "the floating box shadows that floor point";
  const auto seen = FirstHit(*scene, scene->cameras[0].pose.eye, floorPoint - Vec3(0, 1e-3f, 0));
  ASSERT_TRUE(seen.has_value());
  EXPECT_EQ(scene->MaterialOf(*seen).name, "floor") << "the front camera sees the shadowed floor";
  EXPECT_FALSE(FirstHit(*plain, floorPoint + Vec3(0, 1e-3f, 0), lamp).has_value())
      << "lit in the box without the floating box";
}

TEST(RepositoryObjectScenesTest, CornellBoxAnimatedLoopsItsBoxThroughFreeSpace) {
  auto scene = LoadScene(SourceDir() / "scenes/cornell-box-animated.json");
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  ASSERT_EQ(scene->objects.size(), 1u);
  const MovableObject& box = scene->objects[0];
  ASSERT_TRUE(box.animation.has_value());
  EXPECT_TRUE(box.animation->loop);
  EXPECT_GE(box.animation->keys.size(), 2u);
  EXPECT_EQ(box.animation->keys.front().objectToWorld, box.animation->keys.back().objectToWorld)
      << "a seamless loop";
  // All along its path it stays inside the room, above the floor and below
  // the lamp, clear of the two boxes.
  for (double t = 0.0; t <= box.animation->DurationS(); t += 0.05) {
    ScenePose pose = ScenePose::Initial(*scene);
    pose.objectToWorld[0] = box.animation->At(t);
    const Bounds3 world = WorldBounds(*scene, pose, 0);
    EXPECT_GT(world.min.y, 0.25f) << "t = " << t;
    EXPECT_LT(world.max.y, 1.5f) << "t = " << t;
    EXPECT_GT(world.min.x, -0.98f) << "t = " << t;
    EXPECT_LT(world.max.x, -0.1f) << "t = " << t;
    EXPECT_GT(world.min.z, 0.12f) << "t = " << t;
    EXPECT_LT(world.max.z, 0.98f) << "t = " << t;
  }
}


TEST(RepositoryObjectScenesTest, BreakfastRoomChairIsAMovableGroupOfThreePartsThatShadowsSunlitFloor) {
  if (!fs::exists(SharedScene("breakfast-room/breakfast-room.obj")))
    GTEST_SKIP() << "../shared/scenes/breakfast-room is absent (clone ../shared beside the source tree)";
  auto scene = LoadScene(SourceDir() / "scenes/breakfast-room-chair.json");
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  ASSERT_EQ(scene->objects.size(), 1u);
  const MovableObject& chair = scene->objects[0];
  EXPECT_EQ(chair.name, "chair");
  // Mesh010 + Mesh036 + Mesh027: 13,248 + 14,480 + 2,320 faces in the OBJ.
  EXPECT_NEAR(double(chair.triangleCount), 30048.0, 50.0);
  EXPECT_NEAR(double(scene->triangles.size()), 269538.0, 50.0);
  std::vector<std::string> materials;
  for (uint32_t t = chair.firstTriangle; t < chair.firstTriangle + chair.triangleCount; ++t)
    if (std::find(materials.begin(), materials.end(), scene->MaterialOf(t).name) == materials.end())
      materials.push_back(scene->MaterialOf(t).name);
  std::sort(materials.begin(), materials.end());
  EXPECT_EQ(materials, (std::vector<std::string>{"BlackRubber", "Chrome", "WhitePlastic"}));
  const Bounds3 world = WorldBounds(*scene, ScenePose::Initial(*scene), 0);
  ExpectNear(world.min, Vec3(-2.55f, -1.41f, -1.0f), 0.02f, "chair min");
  ExpectNear(world.max, Vec3(-1.12f, 1.17f, 0.73f), 0.02f, "chair max");
  ExpectNear(chair.objectToWorld.translation, world.Center(), 1e-4f, "pivot at the centre of its bounds");
  EXPECT_NEAR(world.min.y, -1.41f, 0.02f) << "standing on the floor (y = -1.42)";

  // Moving it changes what the sun does: on a 0.25 grid of the floor around
  // it, points whose way to the sun the chair (and nothing else) blocks.
  const ScenePose pose = ScenePose::Initial(*scene);
  std::vector<WorldTriangle> triangles(scene->triangles.size());
  for (uint32_t t = 0; t < triangles.size(); ++t)
    triangles[t] = {WorldPointAt(*scene, pose, t, 0, 0), WorldPointAt(*scene, pose, t, 1, 0),
                    WorldPointAt(*scene, pose, t, 0, 1)};
  // Nearest triangle the ray from `origin` along `direction` meets, among
  // [0, end).
  auto nearest = [&](const Vec3& origin, const Vec3& direction, uint32_t end) -> std::optional<uint32_t> {
    std::optional<uint32_t> best;
    float bestDistance = std::numeric_limits<float>::max();
    for (uint32_t t = 0; t < end; ++t) {
      const WorldTriangle& w = triangles[t];
      const Vec3 e1 = w[1] - w[0], e2 = w[2] - w[0];
      const Vec3 p = glm::cross(direction, e2);
      const float det = glm::dot(e1, p);
      if (std::abs(det) < 1e-12f) continue;
      const Vec3 s = origin - w[0];
      const float u = glm::dot(s, p) / det;
      if (u < 0.0f || u > 1.0f) continue;
      const Vec3 q = glm::cross(s, e1);
      const float v = glm::dot(direction, q) / det;
      if (v < 0.0f || u + v > 1.0f) continue;
      const float distance = glm::dot(e2, q) / det;
      if (distance > 1e-3f && distance < bestDistance) {
        bestDistance = distance;
        best = t;
      }
    }
    return best;
  };
  const Vec3 toSun = scene->sun->directionToSun;
  int inChairShadow = 0;
  for (float x = world.min.x - 4.0f; x <= world.max.x + 0.5f; x += 0.25f)
    for (float z = world.min.z - 1.0f; z <= world.max.z + 1.5f; z += 0.25f) {
      const Vec3 floor(x, -1.40f, z);
      const auto blocker = nearest(floor, toSun, uint32_t(triangles.size()));
      if (blocker && scene->ObjectOfTriangle(*blocker) == 0 && !nearest(floor, toSun, scene->staticTriangleCount))
        ++inChairShadow;
    }
  EXPECT_GE(inChairShadow, 8) << "floor points in the chair's sun shadow (13 when written)";
}

}  // namespace
}  // namespace penumbra
