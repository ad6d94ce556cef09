// Moving objects in the SMA (issue 14) without sockets: MoveObject checks,
// coalescing, the next pose, what a move invalidates, the wire fields of
// SceneInfo, MOVED and new vertices, and visibility at a moved pose.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <set>
#include <vector>

#include "hierarchy_test_scenes.h"
#include "penumbra/common/embree_scene.h"
#include "penumbra/sma/delta.h"
#include "penumbra/sma/move_prediction.h"
#include "penumbra/sma/scene_moves.h"
#include "penumbra/sma/visibility.h"

namespace penumbra::sma {
namespace {

// A 4x4 static floor on y = 0 around the origin; object 0 ("box"): a unit
// quad, facing +y in object space, placed 1 above the floor's centre;
// object 1 ("spinner"): a small quad far off, animated.
Scene FloorWithObjects() {
  SceneBuilder b;
  const uint32_t m = b.AddMaterial(Material{});
  b.AddQuad(Vec3(-2.0f, 0.0f, -2.0f), Vec3(0, 0, 4), Vec3(4, 0, 0), m);
  MovableObject box;
  box.name = "box";
  box.objectToWorld = RigidTransform{glm::mat3(1.0f), Vec3(0.0f, 1.0f, 0.0f)};
  b.BeginObject(box);
  b.AddQuad(Vec3(-0.5f, 0.0f, -0.5f), Vec3(0, 0, 1), Vec3(1, 0, 0), m);
  MovableObject spinner;
  spinner.name = "spinner";
  spinner.objectToWorld = RigidTransform{glm::mat3(1.0f), Vec3(10.0f, 1.0f, 0.0f)};
  ObjectAnimation path;
  path.keys = {ObjectKeyframe{0.0f, spinner.objectToWorld},
               ObjectKeyframe{1.0f, RigidTransform{glm::mat3(1.0f), Vec3(10.0f, 2.0f, 0.0f)}}};
  spinner.animation = path;
  b.BeginObject(spinner);
  b.AddQuad(Vec3(-0.1f, 0.0f, -0.1f), Vec3(0, 0, 0.2f), Vec3(0.2f, 0, 0), m);
  b.EndObject();
  Scene s;
  s.name = "floor-with-objects";
  s.twoSided = true;
  const Status built = b.BuildInto(s);
  EXPECT_TRUE(built.ok()) << built.error().message;
  return s;
}

wire::MoveObject Move(uint32_t id, std::vector<float> m12) {
  wire::MoveObject m;
  m.set_request_id(7);
  m.set_object(id);
  for (float f : m12) m.add_object_to_world(f);
  return m;
}

std::vector<float> Translation(float x, float y, float z) { return {1, 0, 0, x, 0, 1, 0, y, 0, 0, 1, z}; }

TEST(SceneMoves, CheckMoveObjectRefusesWhatCannotBeAMoveAndNamesIt) {
  const Scene scene = FloorWithObjects();
  ASSERT_EQ(scene.objects.size(), 2u);
  const auto refused = [&](const wire::MoveObject& m, const std::string& word) {
    auto checked = CheckMoveObject(m, scene);
    if (checked) return ::testing::AssertionFailure() << "accepted";
    if (checked.error().message.find(word) == std::string::npos)
      return ::testing::AssertionFailure() << "message '" << checked.error().message << "' lacks '" << word << "'";
    return ::testing::AssertionSuccess();
  };
  EXPECT_TRUE(refused(Move(0, Translation(0, 1, 0)), "unknown object id 0"));
  EXPECT_TRUE(refused(Move(3, Translation(0, 1, 0)), "unknown object id 3"));
  EXPECT_TRUE(refused(Move(2, Translation(0, 1, 0)), "animated"));
  EXPECT_TRUE(refused(Move(1, {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1}), "12"));
  std::vector<float> nan = Translation(0, 1, 0);
  nan[3] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_TRUE(refused(Move(1, nan), "box"));
  EXPECT_FALSE(CheckMoveObject(Move(1, {2, 0, 0, 0, 0, 2, 0, 0, 0, 0, 2, 0}), scene)) << "scaled";
  EXPECT_FALSE(CheckMoveObject(Move(1, {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, -1, 0}), scene)) << "mirrored";
  EXPECT_FALSE(CheckMoveObject(Move(1, {1, 1, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0}), scene)) << "sheared";
  EXPECT_FALSE(CheckMoveObject(Move(1, std::vector<float>(12, 0.0f)), scene)) << "degenerate";

  auto ok = CheckMoveObject(Move(1, Translation(0.5f, 1.0f, 0.0f)), scene);
  ASSERT_TRUE(ok) << ok.error().message;
  EXPECT_EQ(ok->object, 0u);
  EXPECT_EQ(ok->objectToWorld.translation, Vec3(0.5f, 1.0f, 0.0f));

  auto none = Scene();
  EXPECT_FALSE(CheckMoveObject(Move(1, Translation(0, 0, 0)), scene.objects.empty() ? scene : none));
}

TEST(SceneMoves, NextPoseCountsEpochsAndSkipsMovesThatChangeNothing) {
  const Scene scene = FloorWithObjects();
  const ScenePose initial = ScenePose::Initial(scene);
  EXPECT_FALSE(NextPose(initial, std::vector{ObjectMove{0, scene.objects[0].objectToWorld}}));
  // The place as announced (12 floats), read back: re-orthonormalised, the same place.
  const RigidTransform turned = RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.3f, Vec3(1, 2, 3));
  ScenePose at = initial;
  at.objectToWorld[0] = turned;
  const auto m12 = turned.ToRowMajor();
  auto readBack = RigidTransform::FromRowMajor(m12);
  ASSERT_TRUE(readBack);
  EXPECT_FALSE(NextPose(at, std::vector{ObjectMove{0, *readBack}}));
  const RigidTransform away{glm::mat3(1.0f), Vec3(1.0f, 1.0f, 0.0f)};
  auto next = NextPose(initial, std::vector{ObjectMove{0, away}});
  ASSERT_TRUE(next);
  EXPECT_EQ(next->epoch, 1u);
  EXPECT_EQ(next->objectToWorld[0], away);
  EXPECT_EQ(next->objectToWorld[1], initial.objectToWorld[1]);
}

TEST(SceneMoves, CoalescerKeepsTheLatestMovePerObjectAndOneJob) {
  MoveCoalescer q;
  const auto at = [](float x) { return RigidTransform{glm::mat3(1.0f), Vec3(x, 0.0f, 0.0f)}; };
  EXPECT_TRUE(q.Add(ObjectMove{0, at(1)})) << "first: post the job";
  EXPECT_FALSE(q.Add(ObjectMove{0, at(2)})) << "the job is posted";
  EXPECT_FALSE(q.Add(ObjectMove{1, at(3)}));
  auto moves = q.Take();
  ASSERT_EQ(moves.size(), 2u);
  EXPECT_EQ(moves[0].object, 0u);
  EXPECT_EQ(moves[0].objectToWorld, at(2));
  EXPECT_EQ(moves[1].objectToWorld, at(3));
  EXPECT_EQ(q.Coalesced(), 1u);
  // While the job applies them, a new move waits for the job's next Take.
  EXPECT_FALSE(q.Add(ObjectMove{0, at(4)}));
  EXPECT_EQ(q.Take().size(), 1u);
  EXPECT_TRUE(q.Take().empty()) << "nothing left: the job ends";
  EXPECT_TRUE(q.Add(ObjectMove{0, at(5)})) << "a new job";
}

TEST(SceneMoves, PlanInvalidationTakesTheMovedObjectsVerticesAndWhatTheMotionVolumeReaches) {
  const Scene scene = FloorWithObjects();
  Hierarchy hierarchy(scene);
  hierarchy.Refine(0, RefineOptions{});  // midpoints on the floor
  const NodeId boxRoot = NodeId(scene.objects[0].firstTriangle);
  hierarchy.Refine(boxRoot, RefineOptions{});  // and on the box
  SampleCache cache;
  cache.Reserve(hierarchy.VertexCount());
  std::vector<ShadedSample> all;
  for (VertexId v = 0; v < hierarchy.VertexCount(); ++v) all.push_back(ShadedSample{v, Rgb(1.0f), Rgb(2.0f), 0.1f, 16});
  cache.Store(all);

  const ScenePose before = ScenePose::Initial(scene);
  EXPECT_TRUE(PlanInvalidation(hierarchy, cache, before, before).vertices.empty()) << "nothing moved";
  ScenePose after = *NextPose(before, std::vector{ObjectMove{0, RigidTransform{glm::mat3(1.0f), Vec3(1, 1, 0)}}});
  const Invalidation inv = PlanInvalidation(hierarchy, cache, before, after);

  size_t boxVertices = 0;
  for (VertexId v = 0; v < hierarchy.VertexCount(); ++v)
    boxVertices += scene.ObjectOfTriangle(hierarchy.GetVertex(v).baseTriangle) == 0;
  EXPECT_GT(boxVertices, 8u);  // base vertices of both sides and midpoints
  EXPECT_EQ(inv.objectVertices, boxVertices);
  EXPECT_TRUE(std::is_sorted(inv.vertices.begin(), inv.vertices.end()));
  EXPECT_TRUE(std::adjacent_find(inv.vertices.begin(), inv.vertices.end()) == inv.vertices.end());
  // The motion-volume test adds floor vertices the box's move may change,
  // never more than there are.
  EXPECT_GT(inv.vertices.size(), inv.objectVertices);
  EXPECT_LE(inv.vertices.size(), hierarchy.VertexCount());
  // A full recomputation takes every vertex, whatever the test says.
  const Invalidation full = PlanInvalidation(hierarchy, cache, before, after, InvalidationRule::kEverything);
  EXPECT_EQ(full.vertices.size(), hierarchy.VertexCount());
  EXPECT_EQ(full.objectVertices, boxVertices);
}

// After InvalidateUnshaded, a plan lists what the cache holds only: a vertex
// with no sample needs nothing more (the floor refuses its old samples)
// unless it awaits a reshade a client wants, and chunks of ids the cache
// never wrote are skipped whole -- most of a large scene's, on every move.
TEST(SceneMoves, PlanInvalidationListsWhatTheCacheHoldsAndWhatAwaitsAReshade) {
  constexpr VertexId kChunk = VertexId(SampleCache::kChunkVertices);
  const Scene scene = FloorWithObjects();
  Hierarchy hierarchy(scene);
  for (int round = 0; round < 8 && hierarchy.VertexCount() < 3 * kChunk; ++round)
    for (NodeId leaf : Leaves(hierarchy)) hierarchy.Refine(leaf, RefineOptions{});
  ASSERT_GE(hierarchy.VertexCount(), 3 * kChunk);
  SampleCache cache;
  cache.Reserve(hierarchy.VertexCount());
  // Samples of the even ids of the first chunk only (the box's base
  // vertices among them); one of them then invalidated by an earlier move.
  std::vector<ShadedSample> some;
  for (VertexId v = 0; v < kChunk; v += 2) some.push_back(ShadedSample{v, Rgb(1.0f), Rgb(2.0f), 0.1f, 16});
  cache.Store(some);
  const VertexId awaiting = 2 * 17;
  ASSERT_NE(scene.ObjectOfTriangle(hierarchy.GetVertex(awaiting).baseTriangle), 0u);
  ASSERT_TRUE(cache.Invalidate(awaiting, 1));
  ASSERT_FALSE(cache.HasChunk(kChunk)) << "nothing written beyond the first chunk";

  const ScenePose before = ScenePose::Initial(scene);
  ScenePose after = *NextPose(before, std::vector{ObjectMove{0, RigidTransform{glm::mat3(1.0f), Vec3(1, 1, 0)}}});
  cache.InvalidateUnshaded(after.epoch);
  const Invalidation inv = PlanInvalidation(hierarchy, cache, before, after);
  size_t boxVertices = 0;
  for (VertexId v : inv.vertices) {
    EXPECT_LT(v, kChunk) << "a vertex of a chunk the cache never wrote";
    const bool ofTheBox = scene.ObjectOfTriangle(hierarchy.GetVertex(v).baseTriangle) == 0;
    boxVertices += ofTheBox;
    EXPECT_TRUE(ofTheBox || v % 2 == 0) << v << ": never shaded, not the box's, listed";
  }
  EXPECT_GT(boxVertices, 0u);
  EXPECT_EQ(inv.objectVertices, boxVertices);
  EXPECT_TRUE(std::binary_search(inv.urgent.begin(), inv.urgent.end(), awaiting))
      << "a vertex awaiting its reshade is urgent (a client holding it asks for it first)";
}

// A sample is judged against the pose it was shaded at: a tiny move far
// away must still invalidate floor samples shaded while the box hung over
// them (two moves ago), or many small moves, each below the tolerance,
// would leave them wrong by their sum.
TEST(SceneMoves, PlanInvalidationJudgesEachSampleAgainstThePoseItWasShadedAt) {
  const Scene scene = FloorWithObjects();
  Hierarchy hierarchy(scene);
  hierarchy.Refine(0, RefineOptions{});
  SampleCache cache;
  cache.Reserve(hierarchy.VertexCount());
  std::vector<ShadedSample> floor;
  for (VertexId v = 0; v < hierarchy.VertexCount(); ++v)
    if (scene.ObjectOfTriangle(hierarchy.GetVertex(v).baseTriangle) == kStaticObject &&
        hierarchy.GetVertex(v).normal.y > 0.0f)
      floor.push_back(ShadedSample{v, Rgb(0.5f), Rgb(2.0f), 0.01f, 1024, 0, /*epoch=*/0});
  ASSERT_FALSE(floor.empty());
  cache.Store(floor);

  const auto at = [&](const ScenePose& from, Vec3 where) {
    const std::optional<ScenePose> next =
        NextPose(from, std::vector{ObjectMove{0, RigidTransform{glm::mat3(1.0f), where}}});
    EXPECT_TRUE(next.has_value()) << "not a move";
    return next.value_or(from);
  };
  auto p0 = std::make_shared<const ScenePose>(ScenePose::Initial(scene));  // box 1 above the floor's middle
  auto p1 = std::make_shared<const ScenePose>(at(*p0, Vec3(1000.0f, 1.0f, 0.0f)));
  const ScenePose p2 = at(*p1, Vec3(1000.05f, 1.0f, 0.0f));  // a small move, far away
  // Of the cached floor samples (uncached vertices are always invalidated: free).
  std::set<VertexId> cachedFloor;
  for (const ShadedSample& f : floor) cachedFloor.insert(f.vertex);
  const auto floorInvalidated = [&](const Invalidation& inv) {
    size_t n = 0;
    for (VertexId v : inv.vertices) n += cachedFloor.contains(v);
    return n;
  };
  // Judged against the pose before the move only: the far move changes nothing here.
  EXPECT_EQ(floorInvalidated(PlanInvalidation(hierarchy, cache, *p1, p2)), 0u);
  // Judged against the pose they were shaded at (epoch 0, the 1 m square 1 m
  // overhead): the floor's middle and its edges' midpoints see it under a
  // projected solid angle of 0.044 sr or more, above tau / L = 0.02 / 1
  // (1 % of E = 2; L = twice the cached radiance 0.5), and are invalidated;
  // its corners, 2.1 m out on both axes, see it under 0.013 sr and keep
  // theirs.
  PoseHistory history;
  history.Record(p0);
  history.Record(p1);
  const Invalidation judged = PlanInvalidation(hierarchy, cache, *p1, p2, InvalidationRule::kTest, &history);
  size_t near = 0;
  for (const ShadedSample& f : floor) {
    const Vec3 place = hierarchy.GetVertex(f.vertex).position;
    const bool isNear = std::abs(place.x) < 1.9f || std::abs(place.z) < 1.9f;
    near += isNear;
    EXPECT_EQ(std::binary_search(judged.vertices.begin(), judged.vertices.end(), f.vertex), isNear)
        << "floor vertex at (" << place.x << ", " << place.z << ")";
  }
  EXPECT_GE(near, 3u);
  EXPECT_LT(near, floor.size());
  // A history too small to keep epoch 0: the floor's samples cannot be
  // judged, so they go, whatever the move.
  PoseHistory shortHistory(PoseHistory::BytesOf(*p1));
  shortHistory.Record(p0);
  shortHistory.Record(p1);
  ASSERT_EQ(shortHistory.At(0), nullptr) << "forgotten";
  ASSERT_NE(shortHistory.At(1), nullptr);
  const Invalidation forgotten = PlanInvalidation(hierarchy, cache, *p1, p2, InvalidationRule::kTest, &shortHistory);
  EXPECT_EQ(floorInvalidated(forgotten), floor.size());
  for (const ShadedSample& f : floor)
    EXPECT_TRUE(std::binary_search(forgotten.urgent.begin(), forgotten.urgent.end(), f.vertex)) << "urgently";
}

TEST(SceneMoves, PoseHistoryKeepsTheNewestPosesWithinItsBytes) {
  const Scene scene = FloorWithObjects();
  std::vector<std::shared_ptr<const ScenePose>> poses;
  for (uint64_t e = 0; e < 10; ++e) {
    ScenePose pose = ScenePose::Initial(scene);
    pose.epoch = e;
    poses.push_back(std::make_shared<const ScenePose>(pose));
  }
  const size_t each = PoseHistory::BytesOf(*poses[0]);
  PoseHistory history(4 * each);
  for (uint64_t e : {0, 1, 2, 4, 5, 7, 8, 9}) history.Record(poses[e]);  // 3 and 6 never applied
  history.Record(poses[8]);  // out of order: ignored
  EXPECT_EQ(history.Size(), 4u);
  EXPECT_LE(history.Bytes(), 4 * each);
  EXPECT_EQ(history.Newest(), std::optional<uint64_t>(9));
  for (uint64_t e : {0, 1, 2, 4, 6}) EXPECT_EQ(history.At(e), nullptr) << "epoch " << e;
  for (uint64_t e : {5, 7, 8, 9}) {
    ASSERT_NE(history.At(e), nullptr) << "epoch " << e;
    EXPECT_EQ(history.At(e)->epoch, e);
  }
  // Never empty: a pose bigger than the budget is still the newest.
  PoseHistory tiny(1);
  tiny.Record(poses[3]);
  EXPECT_NE(tiny.At(3), nullptr);
}

TEST(SceneMoves, SceneInfoAndMovedDeltaNameObjectsByIdWithTheirTransforms) {
  const Scene scene = FloorWithObjects();
  ScenePose pose = ScenePose::Initial(scene);
  pose.objectToWorld[0] = RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.5f, Vec3(0.25f, 1.0f, 0.0f));
  pose.epoch = 4;
  wire::SceneInfo info;
  info.add_objects()->set_name("left over");  // replaced, not added to
  FillSceneInfoObjects(scene, pose, &info);
  ASSERT_EQ(info.objects_size(), 2);
  EXPECT_EQ(info.scene_epoch(), 4u);
  EXPECT_EQ(info.objects(0).object(), 1u);
  EXPECT_EQ(info.objects(0).name(), "box");
  EXPECT_FALSE(info.objects(0).animated());
  EXPECT_TRUE(info.objects(1).animated());
  EXPECT_EQ(info.objects(1).object(), 2u);
  EXPECT_FLOAT_EQ(info.objects(0).bounds_min().x(), -0.5f);  // object space
  EXPECT_FLOAT_EQ(info.objects(0).bounds_max().z(), 0.5f);
  ASSERT_EQ(info.objects(0).object_to_world_size(), 12);
  EXPECT_FLOAT_EQ(info.objects(0).object_to_world(3), 0.25f);
  EXPECT_FLOAT_EQ(info.objects(0).object_to_world(0), std::cos(0.5f));

  wire::Delta delta;
  FillMovedDelta(pose, std::vector<uint32_t>{0}, &delta);
  EXPECT_EQ(delta.kind(), wire::DELTA_KIND_MOVED);
  EXPECT_EQ(delta.scene_epoch(), 4u);
  ASSERT_EQ(delta.moved_objects_size(), 1);
  EXPECT_EQ(delta.moved_objects(0), 1u);
  ASSERT_EQ(delta.moved_object_transforms_size(), 12);
  const auto back = RigidTransform::FromRowMajor(
      std::span<const float>(delta.moved_object_transforms().data(), 12));
  ASSERT_TRUE(back);
  EXPECT_NEAR(back->translation.x, 0.25f, 1e-6f);
}

TEST(SceneMoves, NewVerticesGoInObjectSpaceWithTheirObject) {
  const Scene scene = FloorWithObjects();
  Hierarchy hierarchy(scene);
  SampleCache cache;
  std::vector<ShadedSample> all;
  for (VertexId v = 0; v < hierarchy.VertexCount(); ++v) all.push_back(ShadedSample{v, Rgb(1.0f), Rgb(2.0f), 0.1f, 16});
  cache.Store(all);
  ClientMirror mirror;
  std::vector<NodeId> roots;
  for (NodeId r = 0; r < hierarchy.RootCount(); ++r) roots.push_back(r);
  wire::Delta delta;
  mirror.AppendChanges({}, roots, hierarchy, cache, delta);
  ASSERT_EQ(delta.vertex_objects_size(), delta.vertex_ids_size());
  std::set<uint32_t> objects;
  for (int i = 0; i < delta.vertex_ids_size(); ++i) {
    const VertexId v = VertexId(delta.vertex_ids(i));
    const uint32_t object = scene.ObjectOfTriangle(hierarchy.GetVertex(v).baseTriangle);
    EXPECT_EQ(delta.vertex_objects(i), object == kStaticObject ? 0u : object + 1);
    objects.insert(delta.vertex_objects(i));
    // Object space: the box's corners at y = 0, not at its world y = 1.
    EXPECT_EQ(delta.vertex_positions(3 * i + 1), hierarchy.GetVertex(v).position.y);
    if (object == 0) {
      EXPECT_EQ(delta.vertex_positions(3 * i + 1), 0.0f);
    }
  }
  EXPECT_EQ(objects, (std::set<uint32_t>{0, 1, 2}));
}

// Visibility at a pose: the box hides the floor below it until it moves
// away; turned upside down, a ray from above meets its back.
TEST(SceneMoves, VisibilityTracesAtThePoseAndSidesFollowTheWorldNormal) {
  const Scene scene = FloorWithObjects();
  auto tracer = VisibilityTracer::Build(scene);
  ASSERT_TRUE(tracer) << tracer.error().message;
  CameraView view;
  view.pose.eye = Vec3(0.0f, 5.0f, 0.0f);
  view.pose.target = Vec3(0.0f, 0.0f, 0.0f);
  view.pose.up = Vec3(0.0f, 0.0f, 1.0f);
  view.fovYDeg = 10.0f;
  view.width = 8;
  view.height = 8;
  const auto centre = [&](const HitBuffer& hits) { return hits.hits[size_t(4 * 8 + 4)]; };
  const uint32_t boxFirst = scene.objects[0].firstTriangle;
  const auto onBox = [&](const PixelHit& h) { return h.triangle == boxFirst || h.triangle == boxFirst + 1; };

  HitBuffer initial;
  (*tracer)->Trace(view, initial);
  EXPECT_EQ(initial.epoch, 0u);
  EXPECT_TRUE(onBox(centre(initial)));
  EXPECT_FALSE(centre(initial).backFace);

  ScenePose away = ScenePose::Initial(scene);
  away.epoch = 1;
  away.objectToWorld[0] = RigidTransform{glm::mat3(1.0f), Vec3(5.0f, 1.0f, 0.0f)};
  auto posedAway = (*tracer)->AtPose(away);
  ASSERT_TRUE(posedAway) << posedAway.error().message;
  HitBuffer moved;
  (*tracer)->Trace(view, moved, nullptr, posedAway->get());
  EXPECT_EQ(moved.epoch, 1u);
  EXPECT_LT(centre(moved).triangle, scene.staticTriangleCount) << "the floor, uncovered";

  ScenePose flipped = ScenePose::Initial(scene);
  flipped.epoch = 2;
  flipped.objectToWorld[0] = RigidTransform::FromAxisAngle(Vec3(1, 0, 0), float(M_PI), Vec3(0.0f, 1.0f, 0.0f));
  auto posedFlipped = (*tracer)->AtPose(flipped);
  ASSERT_TRUE(posedFlipped) << posedFlipped.error().message;
  HitBuffer upsideDown;
  (*tracer)->Trace(view, upsideDown, nullptr, posedFlipped->get());
  EXPECT_TRUE(onBox(centre(upsideDown)));
  EXPECT_TRUE(centre(upsideDown).backFace) << "its front now faces the floor";
}


// An object's object-space corners may coincide with static world corners;
// they are not neighbours: refining the object never splits the floor.
TEST(SceneMoves, AdjacencyNeverCrossesFromAnObjectToTheStaticPart) {
  SceneBuilder b;
  const uint32_t m = b.AddMaterial(Material{});
  b.AddQuad(Vec3(-0.5f, 0.0f, -0.5f), Vec3(0, 0, 1), Vec3(1, 0, 0), m);
  MovableObject box;
  box.name = "box";
  box.objectToWorld = RigidTransform{glm::mat3(1.0f), Vec3(0.0f, 1.0f, 0.0f)};
  b.BeginObject(box);
  b.AddQuad(Vec3(-0.5f, 0.0f, -0.5f), Vec3(0, 0, 1), Vec3(1, 0, 0), m);  // the floor's very corners, object space
  b.EndObject();
  Scene scene;
  scene.twoSided = false;
  ASSERT_TRUE(b.BuildInto(scene).ok());
  Hierarchy hierarchy(scene);
  for (VertexId v = 0; v < scene.staticVertexCount; ++v)
    for (VertexId w = scene.staticVertexCount; w < scene.vertices.size(); ++w)
      EXPECT_NE(hierarchy.GetVertex(v).point, hierarchy.GetVertex(w).point) << v << " and " << w;
  const RefineResult result = hierarchy.Refine(NodeId(scene.objects[0].firstTriangle), RefineOptions{});
  ASSERT_FALSE(result.split.empty());
  for (NodeId n : result.split)
    EXPECT_EQ(scene.ObjectOfTriangle(hierarchy.GetNode(n).baseTriangle), 0u) << "node " << n << " split";
  EXPECT_TRUE(hierarchy.Conforming());
}

// Movement prediction (issue 15): an animated object's next step is
// predicted from the step clock; objects clients move only while dragged
// (below).
TEST(MovePredictor, TheNextAnimationStepIsPredictedExactlyAndNothingElseMoves) {
  const Scene scene = FloorWithObjects();
  const MovePredictor predictor(scene, 10.0);
  ScenePose current = predictor.AtStep(ScenePose::Initial(scene), 3);
  current.epoch = 4;
  const RigidTransform box = current.objectToWorld[0];
  for (uint64_t latest : {3u, 4u}) {  // the clock may have played step 4 already
    auto next = predictor.Predict(current, latest);
    ASSERT_TRUE(next) << latest;
    EXPECT_EQ(next->epoch, 5u);
    EXPECT_EQ(next->objectToWorld[0], box) << "a client's object stays";
    EXPECT_EQ(next->objectToWorld[1], scene.objects[1].animation->At(0.4)) << "exactly the path at step 4";
  }
  EXPECT_FALSE(predictor.Predict(current, 6)) << "the pose shows neither step 6 nor 5: no guess";
  // A client moved the box meanwhile: still the spinner's next step.
  current.objectToWorld[0].translation.x += 0.5f;
  auto next = predictor.Predict(current, 3);
  ASSERT_TRUE(next);
  EXPECT_EQ(next->objectToWorld[0], current.objectToWorld[0]);

  // A path that ended rests: nothing moves, nothing is predicted.
  Scene once = FloorWithObjects();
  once.objects[1].animation->loop = false;
  const MovePredictor resting(once, 10.0);
  ScenePose end = resting.AtStep(ScenePose::Initial(once), 12);
  EXPECT_FALSE(resting.Predict(end, 12));
  EXPECT_FALSE(MovePredictor(scene, 0.0).Predict(current, 3)) << "no animation clock";
}

// The box dragged by a client: `places` applied one epoch each, 33 ms apart
// (30 moves/s), through a predictor; returns the pose after the last.
ScenePose Drag(MovePredictor& predictor, ScenePose pose, const std::vector<RigidTransform>& places,
               MovePredictor::Clock::time_point& at) {
  for (const RigidTransform& place : places) {
    ScenePose next = pose;
    next.epoch = pose.epoch + 1;
    next.objectToWorld[0] = place;
    at += std::chrono::milliseconds(33);
    const ObjectMove sent{0, place};
    predictor.Applied(pose, next.epoch, std::span(&sent, 1), at);
    pose = next;
  }
  return pose;
}

RigidTransform BoxAt(const Vec3& translation, float turnRad = 0.0f) {
  return RigidTransform::FromAxisAngle(Vec3(0, 1, 0), turnRad, translation);
}

// A steady drag's next place continues it: a straight line and a steady
// turn at first order, a circle at second order (the order that would
// have predicted the last place better), so the next move lands within
// kMoveConfirmTolerance of the guess.
TEST(MovePredictor, SteadyDragsAreExtrapolatedAndEndedByAPause) {
  const Scene scene = FloorWithObjects();
  ScenePose start = ScenePose::Initial(scene);
  MovePredictor::Clock::time_point at{};

  {  // a straight line, 1 cm per move, turning 2 degrees per move as it goes
    MovePredictor predictor(scene, 0.0);
    EXPECT_FALSE(predictor.Predict(start, 0)) << "nothing dragged yet";
    std::vector<RigidTransform> line;
    for (int k = 1; k <= 4; ++k) line.push_back(BoxAt(Vec3(0.01f * k, 1.0f, 0.0f), 0.035f * k));
    const ScenePose now = Drag(predictor, start, line, at);
    auto next = predictor.Predict(now, 0);
    ASSERT_TRUE(next);
    EXPECT_EQ(next->epoch, now.epoch + 1);
    EXPECT_LT(LargestDisplacement(next->objectToWorld[0], BoxAt(Vec3(0.05f, 1.0f, 0.0f), 0.035f * 5),
                                  scene.objects[0].objectBounds),
              1e-5f);
    EXPECT_EQ(next->objectToWorld[1], now.objectToWorld[1]) << "the spinner's clock is off: it stays";
  }
  {  // a 10 cm circle in 50 moves: first order misses by r*theta^2 = 1.6 mm
    MovePredictor predictor(scene, 0.0);
    const auto onCircle = [](int k) {
      const double a = 2.0 * 3.14159265358979 * k / 50.0;
      return BoxAt(Vec3(float(0.1 * std::sin(a)), 1.0f, float(0.1 * (std::cos(a) - 1.0))));
    };
    std::vector<RigidTransform> circle;
    for (int k = 1; k <= 6; ++k) circle.push_back(onCircle(k));
    const ScenePose now = Drag(predictor, start, circle, at);
    auto next = predictor.Predict(now, 0);
    ASSERT_TRUE(next);
    const float miss = LargestDisplacement(next->objectToWorld[0], onCircle(7), scene.objects[0].objectBounds);
    const float firstOrderMiss = LargestDisplacement(ExtrapolatePlace(std::vector{circle[4], circle[5]}, false),
                                                     onCircle(7), scene.objects[0].objectBounds);
    EXPECT_GT(firstOrderMiss, 1.2e-3f);
    EXPECT_LT(miss, 3e-4f) << "second order: r*theta^3";
    EXPECT_TRUE(SnapToPrediction(ObjectMove{0, onCircle(7)}, now, *next, scene, kMoveConfirmTolerance));

    // The whole circle, each move snapped to its prediction when within the
    // tolerance (as the SMA applies them): every move after the third snaps
    // -- the guesses continue the places sent, not the snapped ones, whose
    // small errors would grow at second order.
    {
      MovePredictor live(scene, 0.0);
      ScenePose pose = start;
      int snaps = 0;
      for (int k = 1; k <= 50; ++k) {
        const ObjectMove sent{0, onCircle(k)};
        ObjectMove applied = sent;
        if (auto guess = live.Predict(pose, 0))
          if (auto snapped = SnapToPrediction(sent, pose, *guess, scene, kMoveConfirmTolerance)) {
            applied = *snapped;
            snaps += k > 3;
          }
        at += std::chrono::milliseconds(100);
        live.Applied(pose, pose.epoch + 1, std::span(&sent, 1), at);
        pose.epoch += 1;
        pose.objectToWorld[0] = applied.objectToWorld;
      }
      EXPECT_EQ(snaps, 47);
    }

    // Another epoch (the spinner, another object) came after the drag's
    // last place: the drag is not guessed to go on by itself.
    ScenePose later = now;
    later.epoch += 1;
    EXPECT_FALSE(predictor.Predict(later, 0));
    // A pause longer than kDragGap: the next place starts a new drag from
    // where the box rested -- first order from two places.
    at += MovePredictor::kDragGap + std::chrono::milliseconds(1);
    ScenePose resumed = now;
    resumed.epoch += 1;
    resumed.objectToWorld[0] = BoxAt(now.objectToWorld[0].translation + Vec3(0.0f, 0.0f, 0.02f));
    const ObjectMove sent{0, resumed.objectToWorld[0]};
    predictor.Applied(now, resumed.epoch, std::span(&sent, 1), at);
    auto guess = predictor.Predict(resumed, 0);
    ASSERT_TRUE(guess);
    EXPECT_NEAR(guess->objectToWorld[0].translation.z, resumed.objectToWorld[0].translation.z + 0.02f, 1e-6f);
    EXPECT_NEAR(guess->objectToWorld[0].translation.x, resumed.objectToWorld[0].translation.x, 1e-6f);
  }
  {  // with the animation clock on: the spinner's next step and the drag's next place together
    MovePredictor predictor(scene, 10.0);
    ScenePose stepped = predictor.AtStep(start, 2);
    std::vector<RigidTransform> line{BoxAt(Vec3(0.01f, 1.0f, 0.0f)), BoxAt(Vec3(0.02f, 1.0f, 0.0f))};
    ScenePose now = Drag(predictor, stepped, line, at);
    auto next = predictor.Predict(now, 2);
    ASSERT_TRUE(next);
    EXPECT_EQ(next->objectToWorld[1], scene.objects[1].animation->At(0.3));
    EXPECT_NEAR(next->objectToWorld[0].translation.x, 0.03f, 1e-6f);
  }
}

// A move within the tolerance of its predicted place is applied there;
// farther, at rest, or of an animated object it is not.
TEST(MovePredictor, SnapToPredictionOnlyWithinTheToleranceOfAPredictedMove) {
  const Scene scene = FloorWithObjects();
  const ScenePose current = ScenePose::Initial(scene);
  ScenePose predicted = current;
  predicted.epoch = 1;
  predicted.objectToWorld[0] = BoxAt(Vec3(0.05f, 1.0f, 0.0f));
  const float tolerance = kMoveConfirmTolerance;

  const ObjectMove near{0, BoxAt(Vec3(0.0504f, 1.0f, 0.0003f))};
  auto snapped = SnapToPrediction(near, current, predicted, scene, tolerance);
  ASSERT_TRUE(snapped);
  EXPECT_EQ(snapped->object, 0u);
  EXPECT_EQ(snapped->objectToWorld, predicted.objectToWorld[0]);
  EXPECT_FALSE(SnapToPrediction(near, current, predicted, scene, 0.0f)) << "snapping off";
  EXPECT_FALSE(SnapToPrediction(ObjectMove{0, BoxAt(Vec3(0.052f, 1.0f, 0.0f))}, current, predicted, scene, tolerance))
      << "2 mm away";
  // 0.8 mm along x and a turn of 0.5 mrad: every transform entry is within
  // 1e-3, but one corner of the box (0.71 m from its origin) moves ~1.08 mm.
  const ObjectMove turned{0, BoxAt(Vec3(0.0508f, 1.0f, 0.0f), 0.5e-3f)};
  EXPECT_TRUE(NearlyEqual(turned.objectToWorld, predicted.objectToWorld[0], tolerance));
  EXPECT_FALSE(SnapToPrediction(turned, current, predicted, scene, tolerance)) << "a corner moves too far";
  // Predicted to rest: a slow drag's first small move is not taken back.
  EXPECT_FALSE(SnapToPrediction(ObjectMove{0, BoxAt(Vec3(0.0f, 1.0f, 0.0005f))}, current, current, scene, tolerance));
  // The spinner is the clock's: never a client's move to snap.
  ScenePose spun = predicted;
  spun.objectToWorld[1].translation.y += 0.1f;
  EXPECT_FALSE(SnapToPrediction(ObjectMove{1, spun.objectToWorld[1]}, current, spun, scene, tolerance));
}

std::vector<ShadedSample> SamplesAt(uint64_t epoch, VertexId first, VertexId count) {
  std::vector<ShadedSample> out;
  for (VertexId v = first; v < first + count; ++v) {
    ShadedSample s;
    s.vertex = v;
    s.radiance = Rgb(0.25f);
    s.paths = 16;
    s.epoch = epoch;
    out.push_back(s);
  }
  return out;
}

// Prepared samples reach the cache only for the pose they were shaded at,
// with the hierarchy's structure unchanged; late answers follow a hit.
TEST(MovePreparation, SamplesAreReleasedOnlyWhenTheMoveLandsWherePredicted) {
  const Scene scene = FloorWithObjects();
  const MovePredictor predictor(scene, 10.0);
  ScenePose current = ScenePose::Initial(scene);
  auto predicted = std::make_shared<ScenePose>(predictor.AtStep(current, 1));
  predicted->epoch = 1;

  MovePreparation prep;
  ASSERT_TRUE(prep.Begin(predicted, /*generation=*/7));
  EXPECT_TRUE(prep.Arrived(SamplesAt(1, 0, 3)).empty()) << "kept until the move";
  EXPECT_TRUE(prep.Arrived(SamplesAt(0, 10, 2)).empty()) << "another epoch's: dropped";
  ScenePose applied = *predicted;  // the move, as the clock makes it
  auto released = prep.Applied(applied, 7);
  EXPECT_TRUE(released.hit);
  EXPECT_EQ(released.preparedEpoch, 1u);
  ASSERT_EQ(released.samples.size(), 3u);
  EXPECT_EQ(prep.Arrived(SamplesAt(1, 3, 2)).size(), 2u) << "late answers for the hit go to the cache";
  EXPECT_EQ(prep.Predicted(), nullptr);
  EXPECT_FALSE(prep.Begin(predicted, 7)) << "an epoch already applied";

  // A miss: the move went elsewhere (a client's move came with it).
  auto next = std::make_shared<ScenePose>(predictor.AtStep(applied, 2));
  next->epoch = 2;
  ASSERT_TRUE(prep.Begin(next, 7));
  EXPECT_TRUE(prep.Arrived(SamplesAt(2, 0, 4)).empty());
  ScenePose elsewhere = *next;
  elsewhere.objectToWorld[0].translation.z += 0.25f;
  const auto missed = prep.Applied(elsewhere, 7);
  EXPECT_FALSE(missed.hit);
  EXPECT_EQ(missed.preparedEpoch, 2u);
  EXPECT_TRUE(missed.samples.empty());
  EXPECT_TRUE(prep.Arrived(SamplesAt(2, 4, 2)).empty()) << "late answers for a miss are dropped";

  // A miss: a collection changed the structure (vertex ids may be reused).
  auto third = std::make_shared<ScenePose>(predictor.AtStep(elsewhere, 3));
  third->epoch = 3;
  ASSERT_TRUE(prep.Begin(third, 7));
  EXPECT_TRUE(prep.Arrived(SamplesAt(3, 0, 4)).empty());
  EXPECT_FALSE(prep.Applied(*third, 8).hit);
  EXPECT_TRUE(prep.Applied(*third, 8).samples.empty());

  // A preparation replaced before its move drops what it kept.
  auto fourth = std::make_shared<ScenePose>(predictor.AtStep(*third, 4));
  fourth->epoch = 4;
  ASSERT_TRUE(prep.Begin(fourth, 8));
  EXPECT_TRUE(prep.Arrived(SamplesAt(4, 0, 5)).empty());
  ASSERT_TRUE(prep.Begin(fourth, 8));

  const MovePreparationCounters c = prep.Counters();
  EXPECT_EQ(c.predictions, 5u);
  EXPECT_EQ(c.hits, 1u);
  EXPECT_EQ(c.misses, 2u);
  EXPECT_EQ(c.samplesArrived, 3u + 2u + 2u + 4u + 2u + 4u + 5u);
  EXPECT_EQ(c.samplesReleased, 5u);
  EXPECT_EQ(c.samplesDropped, 2u + 4u + 2u + 4u + 5u);
}

}  // namespace
}  // namespace penumbra::sma
