#include "penumbra/sma/delta.h"

#include <algorithm>
#include <cmath>
#include <set>

#include <gtest/gtest.h>

namespace penumbra::sma {
namespace {

// Two base triangles forming a unit quad; material 1 is textured.
Scene QuadScene() {
  SceneBuilder b;
  Material plain;
  const uint32_t m0 = b.AddMaterial(plain);
  Material textured;
  Texture t;
  t.width = t.height = 1;
  t.texels = {Rgb(1.0f)};
  textured.albedoTexture = b.AddTexture(t);
  b.AddMaterial(textured);
  b.AddQuad(Vec3(0), Vec3(1, 0, 0), Vec3(0, 0, -1), m0);
  Scene s;
  s.twoSided = false;  // one surface per triangle; two-sided hierarchies have tests of their own
  EXPECT_TRUE(b.BuildInto(s).ok());
  return s;
}

void ShadeAll(const Hierarchy& h, SampleCache& cache) {
  std::vector<ShadedSample> samples;
  for (VertexId v = 0; v < h.VertexCount(); ++v) samples.push_back(ShadedSample{v, Rgb(float(v)), Rgb(1.0f)});
  cache.Store(samples);
}

VisibleSet Visible(std::vector<NodeId> nodes) {
  VisibleSet v;
  std::sort(nodes.begin(), nodes.end());
  v.nodes = nodes;
  v.coverage.assign(nodes.size(), 10);
  return v;
}

// Improvement rounds average in, weighted by paths; the standard error of
// the mean of independent estimates combines as sqrt(sum w_i^2 s_i^2). A
// round out of order, or for an unshaded vertex, changes nothing.
TEST(SampleCacheTest, ImprovementsAverageInWeightedByPaths) {
  SampleCache cache;
  cache.Reserve(4);
  const ShadedSample first{1, Rgb(1.0f), Rgb(2.0f), 0.4f, 16, 0};
  cache.Store(std::span(&first, 1));
  EXPECT_EQ(cache.Paths(1), 16u);
  EXPECT_NEAR(cache.RelativeError(1), 0.4f / Luminance(Rgb(2.0f)), 1e-6f);

  const ShadedSample second{1, Rgb(4.0f), Rgb(8.0f), 0.1f, 48, 1};
  EXPECT_EQ(cache.Improve(std::span(&second, 1)), std::vector<VertexId>{1});
  EXPECT_EQ(cache.Paths(1), 64u);
  EXPECT_EQ(cache.Rounds(1), 1u);
  EXPECT_NEAR(cache.Radiance(1).r, 0.25f * 1.0f + 0.75f * 4.0f, 1e-5f);
  EXPECT_NEAR(cache.Irradiance(1).g, 0.25f * 2.0f + 0.75f * 8.0f, 1e-5f);
  EXPECT_NEAR(cache.IrradianceStdErr(1), std::sqrt(0.25f * 0.25f * 0.16f + 0.75f * 0.75f * 0.01f), 1e-6f);

  const ShadedSample stale{1, Rgb(100.0f), Rgb(100.0f), 0.0f, 64, 1};  // round 1 again
  const ShadedSample skipped{1, Rgb(100.0f), Rgb(100.0f), 0.0f, 64, 3};
  const ShadedSample unshaded{2, Rgb(100.0f), Rgb(100.0f), 0.0f, 64, 1};
  const ShadedSample failed{1, Rgb(0.0f), Rgb(0.0f), 0.0f, 0, 2};  // a renderer gave up on it
  for (const ShadedSample& s : {stale, skipped, unshaded, failed}) EXPECT_TRUE(cache.Improve(std::span(&s, 1)).empty());
  EXPECT_EQ(cache.Paths(1), 64u);
  EXPECT_FALSE(cache.IsShaded(2));
}

// A sample whose paths all found nothing reads black with no spread; from
// few paths that does not show there is nothing to find, so its relative
// error is unknown (infinite: it is improved) until a round finds light or
// kBlackPaths paths have found nothing.
// A lit sample with no spread (every path agreed) needs nothing more.
TEST(SampleCacheTest, ABlackSampleIsNotKnownToBeAccurate) {
  SampleCache cache;
  cache.Reserve(4);
  EXPECT_EQ(cache.RelativeError(0), 0.0f);  // unshaded: nothing to improve
  const ShadedSample black{0, Rgb(0.0f), Rgb(0.0f), 0.0f, 16, 0};
  const ShadedSample agreed{1, Rgb(1.0f), Rgb(2.0f), 0.0f, 16, 0};
  cache.Store(std::span(&black, 1));
  cache.Store(std::span(&agreed, 1));
  EXPECT_TRUE(std::isinf(cache.RelativeError(0)));
  EXPECT_EQ(cache.RelativeError(1), 0.0f);

  // Black from kBlackPaths paths: taken as black (nothing to improve).
  const ShadedSample hidden{2, Rgb(0.0f), Rgb(0.0f), 0.0f, SampleCache::kBlackPaths, 0};
  cache.Store(std::span(&hidden, 1));
  EXPECT_EQ(cache.RelativeError(2), 0.0f);

  // A round of 48 paths finds some light: 16 zeros and 48 paths of mean 0.4.
  const ShadedSample found{0, Rgb(0.2f), Rgb(0.4f), 0.05f, 48, 1};
  EXPECT_EQ(cache.Improve(std::span(&found, 1)), std::vector<VertexId>{0});
  EXPECT_NEAR(Luminance(cache.Irradiance(0)), 0.75f * 0.4f, 1e-6f);
  EXPECT_NEAR(cache.RelativeError(0), 0.75f * 0.05f / (0.75f * 0.4f), 1e-5f);
}

// A client that holds the first base triangle of a shaded quad.
class HeldTriangleMirrorTest : public ::testing::Test {
 protected:
  HeldTriangleMirrorTest() {
    cache.Reserve(h.VertexCount());
    ShadeAll(h, cache);
    const NodeId first = 0;
    mirror.AppendChanges({}, std::span(&first, 1), h, cache, add);
  }
  const Scene s = QuadScene();
  Hierarchy h{s};
  SampleCache cache;
  ClientMirror mirror;
  wire::Delta add;  // what the client was sent
};

TEST_F(HeldTriangleMirrorTest, UpdatesGoOnlyToVerticesTheClientHolds) {
  wire::Delta update;
  std::vector<VertexId> all;
  for (VertexId v = 0; v < h.VertexCount(); ++v) all.push_back(v);
  EXPECT_EQ(mirror.AppendUpdates(all, cache, update), 3u);
  ASSERT_EQ(update.updated_vertex_ids_size(), 3);
  EXPECT_EQ(update.updated_vertex_radiance_size(), 9);
  EXPECT_EQ(update.updated_vertex_irradiance_size(), 9);
  for (uint64_t v : update.updated_vertex_ids()) EXPECT_TRUE(mirror.HoldsVertex(VertexId(v)));
}

// A held vertex held back for a move's test (issue 14) is not sent while
// suspect; the update owed for it stays owed, and goes once the test kept
// the sample. One the test dropped is no longer owed (its reshade will be).
TEST_F(HeldTriangleMirrorTest, AnUpdateOfASuspectVertexStaysOwedUntilItsTestKeepsIt) {
  ASSERT_EQ(add.vertex_ids_size(), 3);
  const VertexId kept = VertexId(add.vertex_ids(0)), dropped = VertexId(add.vertex_ids(1)),
                 plain = VertexId(add.vertex_ids(2));
  const std::optional<uint32_t> keptGeneration = cache.Suspect(kept, 1);
  const std::optional<uint32_t> droppedGeneration = cache.Suspect(dropped, 1);
  ASSERT_TRUE(keptGeneration && droppedGeneration);

  const std::vector<VertexId> owed{kept, dropped, plain};
  wire::Delta whileSuspect;
  std::vector<VertexId> stillOwed;
  EXPECT_EQ(mirror.AppendUpdates(owed, cache, whileSuspect, &stillOwed), 1u);
  ASSERT_EQ(whileSuspect.updated_vertex_ids_size(), 1);
  EXPECT_EQ(VertexId(whileSuspect.updated_vertex_ids(0)), plain);
  std::sort(stillOwed.begin(), stillOwed.end());
  EXPECT_EQ(stillOwed, (std::vector<VertexId>{std::min(kept, dropped), std::max(kept, dropped)}));

  ASSERT_TRUE(cache.Confirm(kept, *keptGeneration));
  ASSERT_TRUE(cache.FailSuspect(dropped, *droppedGeneration));
  wire::Delta afterTests;
  stillOwed.clear();
  EXPECT_EQ(mirror.AppendUpdates(owed, cache, afterTests, &stillOwed), 2u);
  ASSERT_EQ(afterTests.updated_vertex_ids_size(), 2);
  EXPECT_NE(VertexId(afterTests.updated_vertex_ids(0)), dropped);
  EXPECT_NE(VertexId(afterTests.updated_vertex_ids(1)), dropped);
  EXPECT_EQ(afterTests.updated_vertex_radiance(3 * 0), float(afterTests.updated_vertex_ids(0)));
  EXPECT_TRUE(stillOwed.empty()) << "the dropped one's reshade is owed when it arrives, not now";
}

TEST(SampleCacheTest, StoresOnceAndGrows) {
  SampleCache cache;
  cache.Reserve(4);
  EXPECT_FALSE(cache.IsShaded(2));
  EXPECT_FALSE(cache.IsShaded(100));  // beyond the size: simply not shaded
  const ShadedSample a{2, Rgb(1, 2, 3), Rgb(4, 5, 6)};
  EXPECT_EQ(cache.Store(std::span(&a, 1)), 1u);
  EXPECT_TRUE(cache.IsShaded(2));
  EXPECT_EQ(cache.Radiance(2), Rgb(1, 2, 3));
  EXPECT_EQ(cache.Irradiance(2), Rgb(4, 5, 6));
  // A second result for the same vertex is a duplicate: the first stays.
  const ShadedSample again{2, Rgb(9), Rgb(9)};
  EXPECT_EQ(cache.Store(std::span(&again, 1)), 0u);
  EXPECT_EQ(cache.Radiance(2), Rgb(1, 2, 3));
  // A vertex made by refinement after Reserve grows the cache.
  const ShadedSample late{10, Rgb(0.5f), Rgb(0.5f)};
  EXPECT_EQ(cache.Store(std::span(&late, 1)), 1u);
  EXPECT_TRUE(cache.IsShaded(10));
  EXPECT_EQ(cache.ShadedCount(), 2u);
  EXPECT_NEAR(cache.Luminance(10), 0.5f, 1e-6f);
}

TEST(ClientMirrorTest, SendsEachVertexOnceWhileHeld) {
  const Scene s = QuadScene();
  Hierarchy h(s);
  SampleCache cache;
  ShadeAll(h, cache);
  ClientMirror mirror;
  wire::Delta d1;
  const std::vector<NodeId> first = {0};
  EXPECT_EQ(mirror.AppendChanges({}, first, h, cache, d1), 1u);
  EXPECT_EQ(d1.vertex_ids_size(), 3);
  EXPECT_EQ(d1.vertex_positions_size(), 9);
  EXPECT_EQ(d1.triangle_vertices_size(), 3);
  // The second triangle shares the diagonal: only its one new vertex is sent.
  wire::Delta d2;
  const std::vector<NodeId> second = {1};
  mirror.AppendChanges({}, second, h, cache, d2);
  EXPECT_EQ(d2.vertex_ids_size(), 1);
  EXPECT_EQ(mirror.VertexCount(), 4u);
  // Adding a held triangle again sends nothing.
  wire::Delta d3;
  EXPECT_EQ(mirror.AppendChanges({}, second, h, cache, d3), 0u);
  EXPECT_EQ(d3.triangle_ids_size(), 0);
}

// SortedHeld is merged from the changes since it was last asked for: after
// any mix of additions and removals -- a node added then removed, removed
// then added, asked for or not in between -- it is what is held, in order.
TEST(ClientMirrorTest, SortedHeldFollowsAdditionsAndRemovalsInAnyOrder) {
  const Scene s = QuadScene();
  Hierarchy h(s);
  for (int level = 0; level < 3; ++level) {
    std::vector<NodeId> leaves;
    h.ForEachLeaf(kNoNode, [&](NodeId id) { leaves.push_back(id); });
    for (NodeId leaf : leaves) h.Refine(leaf, RefineOptions{});
  }
  SampleCache cache;
  ShadeAll(h, cache);
  const NodeId nodes = NodeId(h.NodeCount());
  ASSERT_GE(nodes, 80u);
  ClientMirror mirror;
  std::set<NodeId> expected;
  uint32_t state = 12345;
  const auto next = [&] { return state = state * 1664525u + 1013904223u; };
  for (int step = 0; step < 300; ++step) {
    std::vector<NodeId> removals, additions;
    for (int i = 0; i < 8; ++i) removals.push_back(NodeId(next() % nodes));
    for (int i = 0; i < 8; ++i) additions.push_back(NodeId(next() % nodes));
    wire::Delta d;
    mirror.AppendChanges(removals, additions, h, cache, d);
    for (NodeId r : removals) expected.erase(r);
    for (NodeId a : additions) expected.insert(a);
    if (next() % 4 == 0) {  // asked for now and then, as plans do
      const std::vector<NodeId>& sorted = mirror.SortedHeld();
      ASSERT_EQ(sorted, std::vector<NodeId>(expected.begin(), expected.end())) << "step " << step;
    }
  }
  EXPECT_EQ(mirror.SortedHeld(), std::vector<NodeId>(expected.begin(), expected.end()));
  EXPECT_EQ(mirror.TriangleCount(), expected.size());
}

TEST(ClientMirrorTest, RemovalsComeFirstSoAFreedVertexIsResent) {
  const Scene s = QuadScene();
  Hierarchy h(s);
  SampleCache cache;
  ShadeAll(h, cache);
  ClientMirror mirror;
  wire::Delta d1;
  const std::vector<NodeId> zero = {0};
  mirror.AppendChanges({}, zero, h, cache, d1);
  // Remove triangle 0 and add triangle 1 in one delta: the client drops the
  // shared vertices on removal, so they must come again with triangle 1.
  wire::Delta d2;
  const std::vector<NodeId> one = {1};
  mirror.AppendChanges(zero, one, h, cache, d2);
  EXPECT_EQ(d2.removed_triangles_size(), 1);
  EXPECT_EQ(d2.vertex_ids_size(), 3);
  EXPECT_FALSE(mirror.Holds(0));
  EXPECT_TRUE(mirror.Holds(1));
  EXPECT_EQ(mirror.VertexCount(), 3u);
}

TEST(ClientMirrorTest, TexturedTrianglesCarryTheirUvs) {
  Scene s = QuadScene();
  s.triangles[1].material = 1;  // textured
  s.triangles[1].uv = {Vec2(0.1f, 0.2f), Vec2(0.3f, 0.4f), Vec2(0.5f, 0.6f)};
  Hierarchy h(s);
  SampleCache cache;
  ShadeAll(h, cache);
  ClientMirror mirror;
  wire::Delta d;
  const std::vector<NodeId> both = {0, 1};
  mirror.AppendChanges({}, both, h, cache, d);
  ASSERT_EQ(d.triangle_uvs_size(), 6);  // only the textured triangle
  EXPECT_FLOAT_EQ(d.triangle_uvs(0), 0.1f);
  EXPECT_FLOAT_EQ(d.triangle_uvs(5), 0.6f);
  EXPECT_EQ(d.triangle_materials(1), 1u);
}

// Memory accounting (issue 15): the mirror's bytes follow what it holds,
// and the hierarchy's follow its refinement.
TEST(MemoryAccountingTest, MirrorAndHierarchyBytesFollowWhatTheyHold) {
  const Scene s = QuadScene();
  Hierarchy h(s);
  const size_t bare = h.MemoryBytes();
  // Root records and base vertex records are made on first use: none yet,
  // then one chunk of each (1024 records).
  EXPECT_LT(bare, 1000 * sizeof(SampleVertex));
  EXPECT_TRUE(h.GetNode(0).IsLeaf());
  EXPECT_GE(h.MemoryBytes(), bare + 1000 * sizeof(Node));
  const size_t withRootRecords = h.MemoryBytes();
  EXPECT_EQ(h.GetVertex(0).depth, 0);
  EXPECT_GE(h.MemoryBytes(), withRootRecords + 1000 * sizeof(SampleVertex));
  const size_t withRoots = h.MemoryBytes();
  RefineOptions options;
  for (int i = 0; i < 4; ++i) {
    std::vector<NodeId> leaves;
    h.ForEachLeaf(kNoNode, [&](NodeId id) { leaves.push_back(id); });
    for (NodeId id : leaves) h.Refine(id, options);
  }
  ASSERT_GT(h.NodeCount(), 200u);
  EXPECT_GT(h.MemoryBytes(), withRoots + (h.NodeCount() - 2) * sizeof(Node));

  SampleCache cache;
  ShadeAll(h, cache);
  ClientMirror mirror;
  const size_t empty = mirror.MemoryBytes();
  std::vector<NodeId> leaves;
  h.ForEachLeaf(kNoNode, [&](NodeId id) { leaves.push_back(id); });
  wire::Delta d;
  mirror.AppendChanges({}, leaves, h, cache, d);
  // At least one heap entry per held triangle and per held vertex.
  EXPECT_GE(mirror.MemoryBytes(), empty + 16 * (mirror.TriangleCount() + mirror.VertexCount()));
  mirror.Clear();
  EXPECT_LT(mirror.MemoryBytes(), 16 * leaves.size());
}

TEST(PlanViewTest, SortsTheDifferenceIntoThePapersLists) {
  const Scene s = QuadScene();
  Hierarchy h(s);
  SampleCache cache;
  // Shade only triangle 0's vertices.
  std::vector<ShadedSample> samples;
  for (VertexId v : h.GetNode(0).v) samples.push_back(ShadedSample{v, Rgb(1.0f), Rgb(1.0f)});
  cache.Store(samples);
  ClientMirror mirror;
  ViewPlan plan = PlanView(Visible({0, 1}), mirror, h, cache);
  EXPECT_EQ(plan.addCached, std::vector<NodeId>{0});
  EXPECT_EQ(plan.pending, std::vector<NodeId>{1});
  ASSERT_EQ(plan.missing.size(), 1u);  // triangle 1 shares two of its corners with 0
  EXPECT_FALSE(cache.IsShaded(plan.missing[0]));
  EXPECT_TRUE(plan.removeGone.empty());
  EXPECT_GT(cache.Misses(), 0u);

  wire::Delta d;
  mirror.AppendChanges({}, plan.addCached, h, cache, d);
  // Triangle 0 leaves the view: it is removed.
  ViewPlan next = PlanView(Visible({1}), mirror, h, cache);
  EXPECT_EQ(next.removeGone, std::vector<NodeId>{0});
  EXPECT_TRUE(next.addCached.empty());
}

TEST(PlanViewTest, ParentReplacedByItsChildrenGoesWithThem) {
  const Scene s = QuadScene();
  Hierarchy h(s);
  SampleCache cache;
  ShadeAll(h, cache);
  ClientMirror mirror;
  wire::Delta d;
  const std::vector<NodeId> roots = {0, 1};
  mirror.AppendChanges({}, roots, h, cache, d);
  h.Refine(0, RefineOptions{});
  ShadeAll(h, cache);
  // Now the children of both roots are visible.
  std::vector<NodeId> children;
  h.ForEachLeaf(kNoNode, [&](NodeId id) { children.push_back(id); });
  const ViewPlan plan = PlanView(Visible(children), mirror, h, cache);
  EXPECT_EQ(plan.removeReplaced, (std::vector<NodeId>{0, 1}));
  EXPECT_TRUE(plan.removeGone.empty());
  EXPECT_EQ(plan.addCached.size(), children.size());
}

// What a session does with a plan (server.cpp, ApplyVisibility).
void Apply(const ViewPlan& plan, ClientMirror& mirror, const Hierarchy& h, const SampleCache& cache) {
  std::vector<NodeId> removals = plan.removeReplaced;
  removals.insert(removals.end(), plan.removeGone.begin(), plan.removeGone.end());
  wire::Delta d;
  mirror.AppendChanges(removals, plan.addCached, h, cache, d);
  mirror.SetLingering(plan.linger);
}

// A triangle that leaves the view stays held within the budget, and when
// the view comes back to it there is nothing to send: it is still there.
TEST(PlanViewTest, ATriangleThatLeftTheViewLingersAndIsThereOnReturn) {
  const Scene s = QuadScene();
  Hierarchy h(s);
  SampleCache cache;
  ShadeAll(h, cache);
  ClientMirror mirror;
  Apply(PlanView(Visible({0}), mirror, h, cache, /*lingerTriangles=*/1), mirror, h, cache);
  const ViewPlan away = PlanView(Visible({1}), mirror, h, cache, 1);
  EXPECT_EQ(away.linger, std::vector<NodeId>{0});
  EXPECT_TRUE(away.removeGone.empty());
  EXPECT_EQ(away.addCached, std::vector<NodeId>{1});
  Apply(away, mirror, h, cache);
  EXPECT_EQ(mirror.TriangleCount(), 2u);
  EXPECT_EQ(mirror.LingeringCount(), 1u);

  const ViewPlan back = PlanView(Visible({0}), mirror, h, cache, 1);
  EXPECT_TRUE(back.addCached.empty());  // shown at once
  EXPECT_TRUE(back.pending.empty());
  EXPECT_EQ(back.linger, std::vector<NodeId>{1});
  Apply(back, mirror, h, cache);
  EXPECT_FALSE(mirror.IsLingering(0));
  EXPECT_TRUE(mirror.IsLingering(1));
  // Without a budget the paper's eager removal, unchanged.
  EXPECT_EQ(PlanView(Visible({1}), mirror, h, cache, 0).removeGone, (std::vector<NodeId>{0}));
}

// The quad with root 0 split once (1 -> 4; root 1 -> 2 across the
// diagonal's midpoint), every vertex shaded.
struct SplitQuad {
  Scene scene = QuadScene();
  Hierarchy h{scene};
  SampleCache cache;
  SplitQuad() {
    h.Refine(0, RefineOptions{});
    ShadeAll(h, cache);
  }
  std::vector<NodeId> Leaves(NodeId under = kNoNode) const {
    std::vector<NodeId> leaves;
    h.ForEachLeaf(under, [&](NodeId id) { leaves.push_back(id); });
    return leaves;
  }
};

// Over the budget, the triangles that left the view longest ago go first.
TEST(PlanViewTest, TheTrianglesThatLeftLongestAgoAreRemovedFirst) {
  SplitQuad quad;
  Hierarchy& h = quad.h;
  SampleCache& cache = quad.cache;
  const std::vector<NodeId> leaves = quad.Leaves();
  ASSERT_GE(leaves.size(), 3u);
  const NodeId a = leaves[0], b = leaves[1], c = leaves[2];
  ClientMirror mirror;
  Apply(PlanView(Visible({a}), mirror, h, cache, 1), mirror, h, cache);
  Apply(PlanView(Visible({b}), mirror, h, cache, 1), mirror, h, cache);  // a lingers
  const ViewPlan third = PlanView(Visible({c}), mirror, h, cache, 1);
  EXPECT_EQ(third.linger, std::vector<NodeId>{b});
  EXPECT_EQ(third.removeGone, std::vector<NodeId>{a});
  Apply(third, mirror, h, cache);
  EXPECT_EQ(mirror.TriangleCount(), 2u);
  EXPECT_FALSE(mirror.Holds(a));
}

// A lingering triangle never overlaps what the view needs: not a node
// whose ancestor or descendant waits for samples (it would show under the
// same pixels), nor one side of a base triangle whose other side is seen
// (the same plane: the two would fight in the depth test).
TEST(PlanViewTest, NothingLingersOverWhatTheViewNeeds) {
  {
    const Scene s = QuadScene();
    Hierarchy h(s);
    h.Refine(0, RefineOptions{});  // root 0 1 -> 4, root 1 1 -> 2 (the diagonal's midpoint)
    SampleCache cache;
    std::vector<ShadedSample> bases;
    for (VertexId v = 0; v < 4; ++v) bases.push_back(ShadedSample{v, Rgb(1.0f), Rgb(1.0f)});
    cache.Store(bases);  // the midpoints stay unshaded
    ClientMirror mirror;
    Apply(PlanView(Visible({1}), mirror, h, cache, 100), mirror, h, cache);
    ASSERT_TRUE(mirror.Holds(1));
    // Root 1's children wait for the midpoint: root 1 may not linger over them.
    std::vector<NodeId> children;
    h.ForEachLeaf(1, [&](NodeId id) { children.push_back(id); });
    ASSERT_EQ(children.size(), 2u);
    const ViewPlan finer = PlanView(Visible(children), mirror, h, cache, 100);
    EXPECT_EQ(finer.pending.size(), 2u);
    EXPECT_EQ(finer.removeGone, std::vector<NodeId>{1});
    EXPECT_TRUE(finer.linger.empty());
  }
  {
    SplitQuad quad;
    Hierarchy& h = quad.h;
    SampleCache& cache = quad.cache;
    const std::vector<NodeId> children = quad.Leaves(0);
    ClientMirror mirror;
    Apply(PlanView(Visible({children[0]}), mirror, h, cache, 100), mirror, h, cache);
    // Its parent is visible again but one of its corners lost its sample: pending.
    const auto& childCorners = h.GetNode(children[0]).v;
    for (VertexId v : h.GetNode(0).v)
      if (std::find(childCorners.begin(), childCorners.end(), v) == childCorners.end()) {
        ASSERT_TRUE(cache.Evict(v));
        break;
      }
    const ViewPlan coarser = PlanView(Visible({0}), mirror, h, cache, 100);
    ASSERT_EQ(coarser.pending, std::vector<NodeId>{0});
    EXPECT_EQ(coarser.removeGone, std::vector<NodeId>{children[0]});
    EXPECT_TRUE(coarser.linger.empty());
  }
  {
    Scene s = QuadScene();
    s.twoSided = true;
    Hierarchy h(s);
    SampleCache cache;
    ShadeAll(h, cache);
    ClientMirror mirror;
    Apply(PlanView(Visible({0}), mirror, h, cache, 100), mirror, h, cache);
    const NodeId backOf0 = h.RootOf(0, /*backFace=*/true), backOf1 = h.RootOf(1, true);
    EXPECT_EQ(PlanView(Visible({backOf1}), mirror, h, cache, 100).linger, std::vector<NodeId>{0});
    const ViewPlan otherSide = PlanView(Visible({backOf0}), mirror, h, cache, 100);
    EXPECT_EQ(otherSide.removeGone, std::vector<NodeId>{0});
    EXPECT_TRUE(otherSide.linger.empty());
  }
}

TEST(DeltaWireBytesTest, MatchesTheEncodedEnvelope) {
  wire::Delta d;
  d.set_view_id(3);
  for (int i = 0; i < 100; ++i) d.add_triangle_ids(uint64_t(i) * 1000);
  wire::Envelope e;
  *e.mutable_delta() = d;
  EXPECT_EQ(DeltaWireBytes(d), 4 + e.ByteSizeLong());
}

}  // namespace
}  // namespace penumbra::sma
