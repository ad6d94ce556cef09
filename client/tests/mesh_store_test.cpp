// MeshStore: delta application in the protocol's order, reference-counted
// vertices, every malformed delta refused, and slot reuse with dirty ranges.

#include "penumbra/client/mesh_store.h"

#include <cmath>
#include <functional>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "expect_near.h"

#include "support/delta_builder.h"

namespace penumbra::client {
namespace {

using testing::DeltaBuilder;

constexpr uint32_t kGrey = 0;      // untextured
constexpr uint32_t kTextured = 1;  // texture 0

class MeshStoreTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const std::vector<int32_t> materialTextures = {-1, 0};
    store_.Reset(materialTextures, 1);
  }

  // A quad of two triangles over vertices 1..4 (sequence 1).
  static DeltaBuilder Quad() {
    DeltaBuilder d(1, 1);
    d.Vertex(1, Vec3(0, 0, 0), Rgb(1.0f)).Vertex(2, Vec3(1, 0, 0), Rgb(2.0f));
    d.Vertex(3, Vec3(1, 1, 0), Rgb(3.0f)).Vertex(4, Vec3(0, 1, 0), Rgb(4.0f));
    d.Triangle(10, {1, 2, 3}, kGrey).Triangle(11, {1, 3, 4}, kGrey);
    return d;
  }

  void ExpectRefused(const wire::Delta& d, const std::string& fragment) {
    auto ok = store_.Apply(d);
    ASSERT_FALSE(ok.ok()) << "accepted a delta that should fail with '" << fragment << "'";
    EXPECT_NE(ok.error().message.find(fragment), std::string::npos) << ok.error().message;
  }

  MeshStore store_;
};

TEST_F(MeshStoreTest, AppliesVerticesThenTrianglesAndCountsReferences) {
  ASSERT_TRUE(store_.Apply(Quad().Pending(7).Delta()).ok());
  EXPECT_EQ(store_.TriangleCount(), 2u);
  EXPECT_EQ(store_.VertexCount(), 4u);
  EXPECT_EQ(store_.VertexRefs(1), 2u);
  EXPECT_EQ(store_.VertexRefs(2), 1u);
  EXPECT_EQ(store_.PendingSamples(), 7u);
  EXPECT_FALSE(store_.Converged());
  EXPECT_EQ(store_.LastSequence(), 1u);
}

// IMPROVED deltas carry better estimates of held vertices: the slot's
// radiance changes and is marked for upload; an update of a vertex not held,
// or an IMPROVED delta carrying triangles, is refused.
TEST_F(MeshStoreTest, AnImprovedVertexChangesInPlace) {
  ASSERT_TRUE(store_.Apply(Quad().Delta()).ok());
  store_.DirtyVertices().Clear();
  ASSERT_TRUE(store_.Apply(DeltaBuilder(2, 1, wire::DELTA_KIND_IMPROVED).Update(3, Rgb(5.0f, 6.0f, 7.0f)).Delta()).ok());
  bool found = false;
  for (const GpuVertex& v : store_.VertexSlots())
    if (v.position[0] == 1.0f && v.position[1] == 1.0f) {
      found = true;
      EXPECT_EQ(v.radiance[0], 5.0f);
      EXPECT_EQ(v.radiance[2], 7.0f);
    }
  EXPECT_TRUE(found);
  EXPECT_FALSE(store_.DirtyVertices().Empty());
  EXPECT_EQ(store_.VertexCount(), 4u);
  EXPECT_EQ(store_.TriangleCount(), 2u);
  ExpectRefused(DeltaBuilder(3, 1, wire::DELTA_KIND_IMPROVED).Update(99, Rgb(1.0f)).Delta(), "vertex 99");
}

TEST_F(MeshStoreTest, AnImprovedDeltaCarriesNoTriangles) {
  DeltaBuilder d = Quad();
  d.Mutable().set_kind(wire::DELTA_KIND_IMPROVED);
  ExpectRefused(d.Delta(), "IMPROVED");
}

TEST_F(MeshStoreTest, AVertexGoesWithItsLastTriangle) {
  ASSERT_TRUE(store_.Apply(Quad().Delta()).ok());
  ASSERT_TRUE(store_.Apply(DeltaBuilder(2, 1, wire::DELTA_KIND_REMOVED).Remove(10).Delta()).ok());
  EXPECT_EQ(store_.TriangleCount(), 1u);
  EXPECT_FALSE(store_.VertexRefs(2).has_value()) << "vertex 2 was used only by triangle 10";
  EXPECT_EQ(store_.VertexRefs(1), 1u);
  EXPECT_EQ(store_.VertexRefs(3), 1u);
}

TEST_F(MeshStoreTest, RemovalsComeFirstSoADroppedVertexCanBeResentInTheSameDelta) {
  ASSERT_TRUE(store_.Apply(Quad().Delta()).ok());
  // Removing 10 drops vertex 2; the SMA then sends it again for triangle 12.
  DeltaBuilder d(2, 1, wire::DELTA_KIND_REFINED);
  d.Remove(10).Vertex(2, Vec3(1, 0, 0), Rgb(2.0f)).Triangle(12, {1, 2, 3}, kGrey).Converged();
  ASSERT_TRUE(store_.Apply(d.Delta()).ok());
  EXPECT_EQ(store_.TriangleCount(), 2u);
  EXPECT_EQ(store_.VertexRefs(2), 1u);
  EXPECT_TRUE(store_.Converged());
}

TEST_F(MeshStoreTest, RefusesRemovalOfATriangleNotHeld) {
  ASSERT_TRUE(store_.Apply(Quad().Delta()).ok());
  ExpectRefused(DeltaBuilder(2, 1).Remove(99).Delta(), "removal of triangle 99");
}

TEST_F(MeshStoreTest, RefusesATriangleWhoseVertexWasNotSent) {
  DeltaBuilder d(1, 1);
  d.Vertex(1, Vec3(0), Rgb(1)).Vertex(2, Vec3(1, 0, 0), Rgb(1)).Triangle(10, {1, 2, 3});
  ExpectRefused(d.Delta(), "uses vertex 3");
}

TEST_F(MeshStoreTest, RefusesAVertexSentWhileHeld) {
  ASSERT_TRUE(store_.Apply(Quad().Delta()).ok());
  DeltaBuilder d(2, 1);
  d.Vertex(1, Vec3(0), Rgb(1)).Vertex(5, Vec3(2, 0, 0), Rgb(1)).Triangle(12, {1, 2, 5});
  ExpectRefused(d.Delta(), "vertex 1 sent while already held");
}

TEST_F(MeshStoreTest, RefusesATriangleAddedTwice) {
  ASSERT_TRUE(store_.Apply(Quad().Delta()).ok());
  ExpectRefused(DeltaBuilder(2, 1).Triangle(10, {1, 2, 3}).Delta(), "triangle 10 added while already held");
}

TEST_F(MeshStoreTest, RefusesAVertexNoTriangleUses) {
  DeltaBuilder d = Quad();
  d.Vertex(5, Vec3(2, 0, 0), Rgb(1));
  ExpectRefused(d.Delta(), "vertex 5 sent but used by no triangle");
}

TEST_F(MeshStoreTest, RefusesArraysOfInconsistentLength) {
  {
    DeltaBuilder d = Quad();
    d.Mutable().mutable_vertex_positions()->RemoveLast();
    ExpectRefused(d.Delta(), "position / radiance / irradiance");
  }
  {
    DeltaBuilder d = Quad();
    d.Mutable().mutable_vertex_irradiance()->Add(0.0f);
    ExpectRefused(d.Delta(), "position / radiance / irradiance");
  }
  {
    DeltaBuilder d = Quad();
    d.Mutable().mutable_triangle_vertices()->RemoveLast();
    ExpectRefused(d.Delta(), "corner vertex ids");
  }
  {
    DeltaBuilder d = Quad();
    d.Mutable().add_triangle_materials(0);
    ExpectRefused(d.Delta(), "materials");
  }
  {  // an untextured triangle carries no texture coordinates
    DeltaBuilder d = Quad();
    for (int i = 0; i < 6; ++i) d.Mutable().add_triangle_uvs(0.5f);
    ExpectRefused(d.Delta(), "texture coordinates for 0 textured triangles");
  }
  {  // a textured one must carry them
    DeltaBuilder d(1, 1);
    d.Vertex(1, Vec3(0), Rgb(1)).Vertex(2, Vec3(1, 0, 0), Rgb(1)).Vertex(3, Vec3(0, 1, 0), Rgb(1));
    d.Triangle(10, {1, 2, 3}, kTextured);
    ExpectRefused(d.Delta(), "texture coordinates for 1 textured triangles");
  }
  EXPECT_EQ(store_.TriangleCount(), 0u) << "shape errors are found before anything is applied";
}

TEST_F(MeshStoreTest, RefusesSequenceGapsAndUnknownKinds) {
  ExpectRefused(DeltaBuilder(2, 1).Delta(), "sequence 2 follows 0");
  ASSERT_TRUE(store_.Apply(Quad().Delta()).ok());
  ExpectRefused(DeltaBuilder(1, 1).Delta(), "sequence 1 follows 1");
  ExpectRefused(DeltaBuilder(3, 1).Delta(), "sequence 3 follows 1");
  ExpectRefused(DeltaBuilder(2, 1, wire::DELTA_KIND_UNSPECIFIED).Delta(), "unknown kind");
  ExpectRefused(DeltaBuilder(2, 1, wire::DELTA_KIND_STATUS).Remove(10).Delta(), "STATUS");
}

TEST_F(MeshStoreTest, RefusesUnknownMaterialsAndValuesThatAreNotFinite) {
  {
    DeltaBuilder d = Quad();
    d.Mutable().set_triangle_materials(0, 2);
    ExpectRefused(d.Delta(), "material 2 but the scene has 2");
  }
  {
    DeltaBuilder d = Quad();
    d.Mutable().set_vertex_radiance(4, std::nanf(""));
    ExpectRefused(d.Delta(), "not finite");
  }
}

TEST_F(MeshStoreTest, ResetEmptiesEverything) {
  ASSERT_TRUE(store_.Apply(Quad().Delta()).ok());
  const std::vector<int32_t> materialTextures = {-1};
  store_.Reset(materialTextures, 0);
  EXPECT_EQ(store_.TriangleCount(), 0u);
  EXPECT_EQ(store_.VertexCount(), 0u);
  EXPECT_EQ(store_.LastSequence(), 0u);
  EXPECT_EQ(store_.Groups().size(), 1u);
  EXPECT_EQ(store_.VertexSlots().size(), 0u);
  ASSERT_TRUE(store_.Apply(Quad().Delta()).ok()) << "sequence starts again at 1";
}

TEST_F(MeshStoreTest, RemovedTriangleSlotIsEmptiedMarkedDirtyAndReused) {
  ASSERT_TRUE(store_.Apply(Quad().Delta()).ok());
  TriangleGroup& grey = store_.Groups()[0];
  ASSERT_EQ(grey.dirty.Take(), (std::vector<SlotRange>{{0, 2}}));
  ASSERT_EQ(store_.DirtyVertices().Take(), (std::vector<SlotRange>{{0, 4}}));

  ASSERT_TRUE(store_.Apply(DeltaBuilder(2, 1, wire::DELTA_KIND_REMOVED).Remove(10).Delta()).ok());
  EXPECT_EQ(grey.dirty.Take(), (std::vector<SlotRange>{{0, 1}}));
  EXPECT_EQ(grey.slots[0].corners[0].material, kEmptyTriangleSlot);
  EXPECT_TRUE(store_.DirtyVertices().Empty()) << "a dropped vertex needs no upload: nothing refers to it";

  // The next triangle takes the freed slot; the arrays do not grow.
  DeltaBuilder d(3, 1, wire::DELTA_KIND_SHADED);
  d.Vertex(5, Vec3(2, 0, 0), Rgb(5.0f)).Triangle(12, {1, 5, 3}, kGrey);
  ASSERT_TRUE(store_.Apply(d.Delta()).ok());
  EXPECT_EQ(grey.allocator.HighWater(), 2u);
  EXPECT_EQ(grey.dirty.Take(), (std::vector<SlotRange>{{0, 1}}));
  EXPECT_EQ(grey.slots[0].corners[0].material, kGrey);
  // Vertex 5 took vertex 2's slot (1).
  EXPECT_EQ(store_.VertexSlots().size(), 4u);
  EXPECT_EQ(store_.DirtyVertices().Take(), (std::vector<SlotRange>{{1, 1}}));
  EXPECT_EQ(grey.slots[0].corners[1].vertexSlot, 1u);
  EXPECT_EQ(store_.VertexSlots()[1].position[0], 2.0f);
}

TEST_F(MeshStoreTest, TexturedTrianglesGoToTheirTextureGroupWithTheirUvs) {
  DeltaBuilder d(1, 1);
  d.Vertex(1, Vec3(0), Rgb(1), Rgb(3)).Vertex(2, Vec3(1, 0, 0), Rgb(1)).Vertex(3, Vec3(0, 1, 0), Rgb(1));
  d.Triangle(10, {1, 2, 3}, kGrey).Triangle(11, {3, 2, 1}, kTextured, std::array<float, 6>{0, 1, 2, 3, 4, 5});
  ASSERT_TRUE(store_.Apply(d.Delta()).ok());
  ASSERT_EQ(store_.Groups().size(), 2u);
  const TriangleGroup& textured = store_.Groups()[1];
  EXPECT_EQ(textured.texture, 0);
  ASSERT_EQ(textured.allocator.Live(), 1u);
  EXPECT_EQ(store_.Groups()[0].allocator.Live(), 1u);
  const GpuTriangle& t = textured.slots[0];
  EXPECT_EQ(t.corners[0].material, kTextured);
  EXPECT_EQ(t.corners[2].uv[0], 4.0f);
  EXPECT_EQ(t.corners[2].uv[1], 5.0f);
  EXPECT_EQ(store_.VertexSlots()[t.corners[2].vertexSlot].irradiance[0], 3.0f);
}

TEST_F(MeshStoreTest, HeldLuminanceIsMeasureLuminanceOfTheHeldVertices) {
  ASSERT_TRUE(store_.Apply(Quad().Delta()).ok());
  auto expectMatches = [&](std::vector<Rgb> held) {
    const ViewLuminance expected = MeasureLuminance(held);
    const ViewLuminance got = store_.HeldLuminance();
    EXPECT_FLOAT_EQ(got.max, expected.max);
    EXPECT_NEAR(got.logAverage, expected.logAverage, 1e-5f * expected.logAverage);
  };
  expectMatches({Rgb(1.0f), Rgb(2.0f), Rgb(3.0f), Rgb(4.0f)});
  // Removing triangle 11 drops vertex 4, the brightest.
  ASSERT_TRUE(store_.Apply(DeltaBuilder(2, 1, wire::DELTA_KIND_REMOVED).Remove(11).Delta()).ok());
  expectMatches({Rgb(1.0f), Rgb(2.0f), Rgb(3.0f)});
  ASSERT_TRUE(store_.Apply(DeltaBuilder(3, 1, wire::DELTA_KIND_REMOVED).Remove(10).Delta()).ok());
  expectMatches({});
}

// --- Movable objects (issue 14) ---------------------------------------------

void AddTransform(wire::Delta& d, uint32_t object, const RigidTransform& t) {
  d.add_moved_objects(object);
  for (float v : t.ToRowMajor()) d.add_moved_object_transforms(v);
}

// A scene with two movable objects: a static triangle (vertices 1-3), one of
// object 1 (4-6) and one of object 2 (7-9), object-space positions equal.
class MeshStoreObjectsTest : public MeshStoreTest {
 protected:
  void SetUp() override {
    const std::vector<int32_t> materialTextures = {-1, 0};
    const std::vector<RigidTransform> objects = {box_, panel_};
    store_.Reset(materialTextures, 1, objects, 3);
  }

  static DeltaBuilder ThreeParts() {
    DeltaBuilder d(1, 1);
    for (uint64_t first : {1, 4, 7}) {
      d.Vertex(first, Vec3(0, 0, 0), Rgb(1.0f)).Vertex(first + 1, Vec3(1, 0, 0), Rgb(1.0f));
      d.Vertex(first + 2, Vec3(0, 1, 0), Rgb(1.0f));
      d.Triangle(first * 10, {first, first + 1, first + 2}, kGrey);
    }
    for (uint32_t object : {0u, 0u, 0u, 1u, 1u, 1u, 2u, 2u, 2u}) d.Mutable().add_vertex_objects(object);
    return d;
  }

  const RigidTransform box_ = RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.5f, Vec3(2, 0, 0));
  const RigidTransform panel_ = RigidTransform::FromAxisAngle(Vec3(1, 0, 0), -0.3f, Vec3(0, 0, 5));
};

// Every vertex the SMA makes lies within its space's bounds: a vertex far
// outside (a hostile peer's, or an SMA bug's) is refused before anything
// changes, static and object-space alike; a point just past the box (within
// 1e-3 of its diagonal: rounding of a midpoint) is not.
TEST_F(MeshStoreObjectsTest, AVertexOutsideItsSpacesBoundsIsRefused) {
  const Bounds3 unit{Vec3(0), Vec3(1, 1, 0)};
  const Bounds3 wide{Vec3(-10), Vec3(10)};
  ASSERT_FALSE(store_.SetVertexBounds(std::vector<Bounds3>{wide, unit}).ok());  // one per space
  ASSERT_FALSE(store_.SetVertexBounds(std::vector<Bounds3>{wide, Bounds3{}, unit}).ok());  // an empty box
  ASSERT_TRUE(store_.SetVertexBounds(std::vector<Bounds3>{wide, unit, unit}).ok());

  DeltaBuilder far = ThreeParts();
  far.Mutable().set_vertex_positions(0, 1e9f);  // static vertex 1
  ExpectRefused(far.Delta(), "vertex 1 at (");
  ExpectRefused(far.Delta(), "outside the scene's bounds");
  EXPECT_EQ(store_.VertexCount(), 0u);
  EXPECT_EQ(store_.LastSequence(), 0u);

  DeltaBuilder outsideObject = ThreeParts();
  outsideObject.Mutable().set_vertex_positions(3 * 4 + 1, 1.01f);  // object 1's vertex 5, y: inside `wide`
  ExpectRefused(outsideObject.Delta(), "object 1's bounds");

  DeltaBuilder rounding = ThreeParts();
  rounding.Mutable().set_vertex_positions(3 * 7, -1e-4f);  // object 2's vertex 8: 1e-4 outside
  EXPECT_TRUE(store_.Apply(rounding.Delta()).ok());
  EXPECT_EQ(store_.VertexCount(), 9u);
}

// Reset forgets the bounds: a new connection's SceneInfo sets them again.
TEST_F(MeshStoreTest, ResetForgetsTheVertexBounds) {
  ASSERT_TRUE(store_.SetVertexBounds(std::vector<Bounds3>{Bounds3{Vec3(5), Vec3(6)}}).ok());
  ExpectRefused(Quad().Delta(), "outside the scene's bounds");
  store_.Reset(std::vector<int32_t>{-1, 0}, 1);
  EXPECT_TRUE(store_.Apply(Quad().Delta()).ok());
}

TEST_F(MeshStoreObjectsTest, AnObjectsVertexIsPlacedByItsTransform) {
  ASSERT_TRUE(store_.Apply(ThreeParts().Delta()).ok());
  EXPECT_EQ(store_.ObjectCount(), 2u);
  EXPECT_EQ(store_.SceneEpoch(), 3u);
  EXPECT_EQ(store_.VertexObject(2), 0u);
  EXPECT_EQ(store_.VertexObject(5), 1u);
  EXPECT_EQ(store_.VertexObject(8), 2u);
  ExpectNear(*store_.WorldPosition(2), Vec3(1, 0, 0));  // static: as sent
  ExpectNear(*store_.WorldPosition(5), box_.ApplyPoint(Vec3(1, 0, 0)));
  ExpectNear(*store_.WorldPosition(9), panel_.ApplyPoint(Vec3(0, 1, 0)));
  EXPECT_FALSE(store_.WorldPosition(99).has_value());
  // The GPU table: entry 0 the identity, entry id the object's rows.
  ASSERT_EQ(store_.ObjectTransforms().size(), 3u);
  EXPECT_EQ(store_.ObjectTransforms()[0].rows[0][0], 1.0f);
  EXPECT_EQ(store_.ObjectTransforms()[0].rows[1][3], 0.0f);
  EXPECT_EQ(store_.ObjectTransforms()[1].rows[0][3], 2.0f);  // the box's translation x
  EXPECT_EQ(store_.ObjectTransforms()[2].rows[2][3], 5.0f);
}

TEST_F(MeshStoreObjectsTest, MovedChangesOnlyThatObjectAndUploadsNoVertex) {
  ASSERT_TRUE(store_.Apply(ThreeParts().Delta()).ok());
  store_.DirtyVertices().Clear();
  (void)store_.TakeObjectTransformsChanged();
  const Vec3 staticBefore = *store_.WorldPosition(2), panelBefore = *store_.WorldPosition(8);

  const RigidTransform moved = RigidTransform::FromAxisAngle(Vec3(0, 0, 1), 1.0f, Vec3(-1, 3, 0.5f));
  DeltaBuilder d(2, 1, wire::DELTA_KIND_MOVED);
  d.Mutable().set_scene_epoch(4);
  AddTransform(d.Mutable(), 1, moved);
  ASSERT_TRUE(store_.Apply(d.Delta()).ok());

  EXPECT_EQ(store_.SceneEpoch(), 4u);
  EXPECT_EQ(store_.MovesApplied(), 1u);
  ExpectNear(*store_.WorldPosition(4), moved.ApplyPoint(Vec3(0, 0, 0)));
  ExpectNear(*store_.WorldPosition(5), moved.ApplyPoint(Vec3(1, 0, 0)));
  ExpectNear(*store_.WorldPosition(6), moved.ApplyPoint(Vec3(0, 1, 0)));
  EXPECT_EQ(*store_.WorldPosition(2), staticBefore);
  EXPECT_EQ(*store_.WorldPosition(8), panelBefore);
  // Nothing re-sent, nothing re-uploaded but the transform table.
  EXPECT_TRUE(store_.DirtyVertices().Empty());
  EXPECT_TRUE(store_.TakeObjectTransformsChanged());
  EXPECT_FALSE(store_.TakeObjectTransformsChanged());
  EXPECT_EQ(store_.VertexCount(), 9u);
  EXPECT_EQ(store_.TriangleCount(), 3u);
  ExpectNear(store_.ConfirmedTransform(1).ApplyPoint(Vec3(1, 2, 3)), moved.ApplyPoint(Vec3(1, 2, 3)));
  EXPECT_EQ(store_.ConfirmedTransform(2), panel_);
  EXPECT_EQ(store_.ObjectTransforms()[1].rows[1][3], 3.0f);
}

TEST_F(MeshStoreObjectsTest, AMovedBeforeAnyViewLeavesTheViewsProgressAlone) {
  DeltaBuilder first = ThreeParts();
  first.Converged().Pending(0);
  ASSERT_TRUE(store_.Apply(first.Delta()).ok());
  ASSERT_TRUE(store_.Converged());
  DeltaBuilder moved(2, 0, wire::DELTA_KIND_MOVED);
  moved.Mutable().set_scene_epoch(4);
  AddTransform(moved.Mutable(), 2, box_);
  ASSERT_TRUE(store_.Apply(moved.Delta()).ok());
  EXPECT_EQ(store_.SceneEpoch(), 4u);
  EXPECT_EQ(store_.LastViewId(), 1u);
  EXPECT_TRUE(store_.Converged());
  EXPECT_EQ(store_.LastSequence(), 2u);
}

TEST_F(MeshStoreObjectsTest, ReshadedUpdatesRadianceInPlace) {
  ASSERT_TRUE(store_.Apply(ThreeParts().Delta()).ok());
  store_.DirtyVertices().Clear();
  DeltaBuilder d(2, 1, wire::DELTA_KIND_RESHADED);
  d.Update(2, Rgb(0.25f), Rgb(0.5f)).Update(5, Rgb(7.0f));
  ASSERT_TRUE(store_.Apply(d.Delta()).ok());
  for (const GpuVertex& v : store_.VertexSlots()) {
    if (v.position[3] == 0.0f && v.position[0] == 1.0f) {
      EXPECT_EQ(v.radiance[0], 0.25f);
      EXPECT_EQ(v.irradiance[0], 0.5f);
    }
    if (v.position[3] == 1.0f && v.position[0] == 1.0f) {
      EXPECT_EQ(v.radiance[1], 7.0f);
    }
  }
  EXPECT_EQ(store_.DirtyVertices().Take(), (std::vector<SlotRange>{{1, 1}, {4, 1}}));
  EXPECT_FLOAT_EQ(store_.HeldLuminance().max, 7.0f);
  // RESHADED carries no geometry, and no moves.
  DeltaBuilder withTriangle = ThreeParts();
  withTriangle.Mutable().set_sequence(3);
  withTriangle.Mutable().set_kind(wire::DELTA_KIND_RESHADED);
  ExpectRefused(withTriangle.Delta(), "RESHADED delta carries triangles");
  DeltaBuilder withMove(3, 1, wire::DELTA_KIND_RESHADED);
  AddTransform(withMove.Mutable(), 1, box_);
  ExpectRefused(withMove.Delta(), "a DELTA_KIND_RESHADED delta carries moved objects");
}

TEST_F(MeshStoreObjectsTest, LocalTransformIsDrawnUntilCleared) {
  ASSERT_TRUE(store_.Apply(ThreeParts().Delta()).ok());
  (void)store_.TakeObjectTransformsChanged();
  const RigidTransform dragged = RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.0f, Vec3(9, 9, 9));
  store_.SetLocalTransform(1, dragged);
  EXPECT_TRUE(store_.TakeObjectTransformsChanged());
  ExpectNear(*store_.WorldPosition(4), Vec3(9, 9, 9));
  EXPECT_EQ(store_.ConfirmedTransform(1), box_);
  store_.SetLocalTransform(1, dragged);
  EXPECT_FALSE(store_.TakeObjectTransformsChanged()) << "the same transform again needs no upload";
  store_.SetLocalTransform(1, std::nullopt);
  EXPECT_TRUE(store_.TakeObjectTransformsChanged());
  ExpectNear(*store_.WorldPosition(4), box_.ApplyPoint(Vec3(0)));
  store_.SetLocalTransform(7, dragged);  // no such object: ignored
  EXPECT_FALSE(store_.TakeObjectTransformsChanged());
}

TEST_F(MeshStoreObjectsTest, BadObjectFieldsAreRefused) {
  // vertex_objects: one per new vertex, ids in range.
  DeltaBuilder missing = ThreeParts();
  missing.Mutable().clear_vertex_objects();
  ExpectRefused(missing.Delta(), "0 vertex objects for 9 new vertices");
  DeltaBuilder outOfRange = ThreeParts();
  outOfRange.Mutable().set_vertex_objects(4, 3);
  ExpectRefused(outOfRange.Delta(), "vertex 5 belongs to object 3, but the scene has 2 movable objects");
  EXPECT_EQ(store_.VertexCount(), 0u);
  DeltaBuilder mixed = ThreeParts();
  mixed.Mutable().set_vertex_objects(4, 2);  // vertex 5 of object 2 in object 1's triangle
  store_.Reset(std::vector<int32_t>{-1, 0}, 1, std::vector<RigidTransform>{box_, panel_}, 3);
  ExpectRefused(mixed.Delta(), "triangle 40 joins vertices of different objects (1, 2, 1)");

  store_.Reset(std::vector<int32_t>{-1, 0}, 1, std::vector<RigidTransform>{box_, panel_}, 3);
  ASSERT_TRUE(store_.Apply(ThreeParts().Delta()).ok());
  auto moved = [](uint64_t sequence) {
    DeltaBuilder d(sequence, 1, wire::DELTA_KIND_MOVED);
    d.Mutable().set_scene_epoch(5);
    return d;
  };
  DeltaBuilder unknown = moved(2);
  AddTransform(unknown.Mutable(), 3, RigidTransform::Identity());
  ExpectRefused(unknown.Delta(), "moves object 3, but the scene's movable objects are 1..2");
  store_.Reset(std::vector<int32_t>{-1, 0}, 1, std::vector<RigidTransform>{box_, panel_}, 3);
  ASSERT_TRUE(store_.Apply(ThreeParts().Delta()).ok());
  DeltaBuilder staticPart = moved(2);
  AddTransform(staticPart.Mutable(), 0, RigidTransform::Identity());
  ExpectRefused(staticPart.Delta(), "moves object 0");

  struct Case {
    std::function<void(wire::Delta&)> breakIt;
    std::string fragment;
  };
  const std::vector<Case> cases = {
      {[](wire::Delta& d) { d.mutable_moved_object_transforms()->RemoveLast(); }, "1 moved objects but 11 transform"},
      {[](wire::Delta& d) { d.set_moved_object_transforms(2, std::nanf("")); }, "transform entry 2 is not finite"},
      {[](wire::Delta& d) { d.set_moved_object_transforms(0, 3.0f); }, "not a rotation"},
      {[](wire::Delta& d) { d.set_scene_epoch(2); }, "MOVED to scene epoch 2, older than the epoch 3"},
      {[](wire::Delta& d) {
         d.add_updated_vertex_ids(1);
         for (int i = 0; i < 3; ++i) {
           d.add_updated_vertex_radiance(1.0f);
           d.add_updated_vertex_irradiance(1.0f);
         }
       },
       "MOVED delta carries radiance updates"},
  };
  for (const Case& c : cases) {
    store_.Reset(std::vector<int32_t>{-1, 0}, 1, std::vector<RigidTransform>{box_, panel_}, 3);
    ASSERT_TRUE(store_.Apply(ThreeParts().Delta()).ok());
    DeltaBuilder d = moved(2);
    AddTransform(d.Mutable(), 1, RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.1f, Vec3(1, 1, 1)));
    c.breakIt(d.Mutable());
    ExpectRefused(d.Delta(), c.fragment);
    EXPECT_EQ(store_.ConfirmedTransform(1), box_) << "a refused move changes nothing: " << c.fragment;
  }
}

TEST_F(MeshStoreTest, AStaticScenesDeltasNeedNoVertexObjects) {
  ASSERT_TRUE(store_.Apply(Quad().Delta()).ok());  // none given
  EXPECT_EQ(store_.VertexObject(1), 0u);
  EXPECT_EQ(store_.ObjectCount(), 0u);
  ASSERT_EQ(store_.ObjectTransforms().size(), 1u);  // the identity
  DeltaBuilder d(2, 1, wire::DELTA_KIND_SHADED);
  d.Vertex(5, Vec3(2, 0, 0), Rgb(5.0f)).Triangle(12, {1, 5, 3}, kGrey);
  d.Mutable().add_vertex_objects(1);
  ExpectRefused(d.Delta(), "vertex 5 belongs to object 1, but the scene has 0 movable objects");
  DeltaBuilder move(2, 1, wire::DELTA_KIND_MOVED);
  AddTransform(move.Mutable(), 1, RigidTransform::Identity());
  ExpectRefused(move.Delta(), "moves object 1, but the scene's movable objects are 1..0");
}

}  // namespace
}  // namespace penumbra::client
