// The collector (issue 15): collapsing refined subtrees keeps the mesh
// conforming and whole, freed ids are reused, and the oldest go first while
// what is young or kept stays.

#include "penumbra/sma/collector.h"

#include <algorithm>
#include <random>
#include <set>

#include <gtest/gtest.h>

#include "hierarchy_test_scenes.h"

namespace penumbra::sma {
namespace {

// Every leaf's area adds up to its base triangle's, every leaf is alive, and
// no T-vertex exists (checked geometrically and by the hierarchy's own test).
void ExpectWholeAndConforming(const Hierarchy& h, const Scene& s, const std::string& when) {
  ASSERT_EQ(CountTVertices(h), 0u) << when;
  ASSERT_TRUE(h.Conforming()) << when;
  for (NodeId root = 0; root < h.RootCount(); ++root) {
    double area = 0.0;
    h.ForEachLeaf(root, [&](NodeId id) {
      ASSERT_TRUE(h.Alive(id)) << when;
      for (VertexId v : h.GetNode(id).v) ASSERT_TRUE(h.VertexAlive(v)) << when;
      area += h.Area(id);
    });
    ASSERT_NEAR(area, s.Area(root % s.triangles.size()), 1e-5) << when << ", root " << root;
  }
}

std::vector<NodeId> CollapsibleNodes(const Hierarchy& h) {
  std::vector<NodeId> out;
  for (NodeId id = 0; id < h.NodeCount(); ++id)
    if (h.Collapsible(id)) out.push_back(id);
  return out;
}

void CollapseEverything(Hierarchy& h, const Scene& s) {
  Hierarchy::CollapseGroup group;
  for (int round = 0; round < 1000; ++round) {
    const auto nodes = CollapsibleNodes(h);
    if (nodes.empty()) return;
    size_t collapsed = 0;
    for (NodeId id : nodes) {
      if (!h.PlanCollapse(id, 1 << 20, group)) continue;
      h.Collapse(group);
      ++collapsed;
      ExpectWholeAndConforming(h, s, "after collapsing " + std::to_string(id));
    }
    ASSERT_GT(collapsed, 0u) << "collapsible nodes remain but no group can collapse";
  }
}

TEST(CollapseTest, RefinementCollapsesBackToTheBaseMesh) {
  for (const bool cube : {false, true}) {
    const Scene s = cube ? CubeScene() : GridScene(4);
    Hierarchy h(s);
    std::mt19937 rng(11);
    for (int step = 0; step < 40; ++step) {
      const auto leaves = Leaves(h);
      h.Refine(leaves[rng() % leaves.size()], RefineOptions{});
    }
    ASSERT_GT(h.NodeCount(), h.RootCount() + 100);
    const uint64_t generation = h.StructureGeneration();
    CollapseEverything(h, s);
    EXPECT_GT(h.StructureGeneration(), generation);
    EXPECT_EQ(h.LiveNodeCount(), h.RootCount()) << (cube ? "cube" : "grid");
    EXPECT_EQ(h.LiveVertexCount(), h.BaseVertexCount());
    EXPECT_EQ(Leaves(h).size(), h.RootCount());
  }
}

class InterleavedCollapseTest : public ::testing::TestWithParam<int> {};

TEST_P(InterleavedCollapseTest, RefineAndCollapseStayConformingAndReuseIds) {
  Scene s = GetParam() % 2 ? CubeScene() : GridScene(5);
  s.twoSided = true;  // back roots collapse too, with points of their own
  Hierarchy h(s);
  std::mt19937 rng{uint32_t(GetParam())};
  Hierarchy::CollapseGroup group;
  size_t peakNodes = 0, peakVertices = 0, collapses = 0;
  for (int step = 0; step < 300; ++step) {
    if (step < 60 || rng() % 2 == 0) {
      const auto leaves = Leaves(h);
      h.Refine(leaves[rng() % leaves.size()], RefineOptions{});
    } else {
      const auto nodes = CollapsibleNodes(h);
      if (!nodes.empty() && h.PlanCollapse(nodes[rng() % nodes.size()], 64, group)) {
        for (NodeId id : group.freedNodes) ASSERT_TRUE(h.Alive(id));
        h.Collapse(group);
        ++collapses;
        for (NodeId id : group.freedNodes) ASSERT_FALSE(h.Alive(id));
        for (VertexId v : group.freedVertices) ASSERT_FALSE(h.VertexAlive(v));
        // The tops (members whose parent is not freed) are leaves now.
        const std::set<NodeId> freed(group.freedNodes.begin(), group.freedNodes.end());
        for (NodeId id : group.nodes)
          if (!freed.contains(id)) {
            ASSERT_TRUE(h.GetNode(id).IsLeaf() && h.WasCollapsed(id));
          }
      }
    }
    ExpectWholeAndConforming(h, s, "after step " + std::to_string(step));
    if (step == 60) {
      peakNodes = h.NodeCount();
      peakVertices = h.VertexCount();
    }
  }
  EXPECT_GT(collapses, 30u);
  // Locate still finds a leaf containing the point, on both sides.
  for (int i = 0; i < 500; ++i) {
    const uint32_t t = rng() % uint32_t(s.triangles.size());
    const float b1 = float(rng() % 1000) / 2000.0f, b2 = float(rng() % 1000) / 2000.0f;
    for (const bool back : {false, true}) {
      const NodeId leaf = h.Locate(t, back, b1, b2, [](const Node&) { return true; });
      ASSERT_TRUE(h.GetNode(leaf).IsLeaf());
      const Triangle& tri = s.triangles[t];
      const Vec3 p = (1 - b1 - b2) * s.vertices[tri.v[0]].position + b1 * s.vertices[tri.v[1]].position +
                     b2 * s.vertices[tri.v[2]].position;
      ASSERT_TRUE(PointInNode(h, leaf, p));
    }
  }
  // Freed ids were reused: the tables grew far less than the splits made.
  EXPECT_LT(h.NodeCount(), 2 * peakNodes);
  EXPECT_LT(h.VertexCount(), 2 * peakVertices);
}

INSTANTIATE_TEST_SUITE_P(Seeds, InterleavedCollapseTest, ::testing::Values(5, 6, 7, 8));

TEST(CollapseTest, RefineAfterCollapseMakesTheSameMesh) {
  // A collapsed region refined again is the same geometry as if it had never
  // been collapsed (new ids, same triangles): the re-shading is the only cost.
  const Scene s = GridScene(3);
  Hierarchy fresh(s), reused(s);
  const std::vector<std::pair<uint32_t, Vec2>> points = {{0, {0.2f, 0.2f}}, {7, {0.6f, 0.1f}}, {12, {0.3f, 0.3f}}};
  const auto refineAt = [&](Hierarchy& h) {
    for (int level = 0; level < 3; ++level)
      for (const auto& [t, b] : points)
        h.Refine(h.Locate(t, false, b.x, b.y, [](const Node&) { return true; }), RefineOptions{});
  };
  refineAt(fresh);
  refineAt(reused);
  CollapseEverything(reused, s);
  RefineResult remade;
  for (int level = 0; level < 3; ++level)
    for (const auto& [t, b] : points) {
      RefineResult r = reused.Refine(reused.Locate(t, false, b.x, b.y, [](const Node&) { return true; }), {});
      remade.remadeVertices += r.remadeVertices;
    }
  EXPECT_GT(remade.remadeVertices, 0u);
  const auto triangles = [](const Hierarchy& h) {
    std::multiset<std::array<float, 9>> out;
    h.ForEachLeaf(kNoNode, [&](NodeId id) {
      std::array<float, 9> t{};
      for (int c = 0; c < 3; ++c)
        for (int k = 0; k < 3; ++k) t[size_t(3 * c + k)] = h.GetVertex(h.GetNode(id).v[c]).position[k];
      out.insert(t);
    });
    return out;
  };
  EXPECT_EQ(triangles(fresh), triangles(reused));
  EXPECT_EQ(fresh.LiveVertexCount(), reused.LiveVertexCount());
}

// Refines around base triangle `t` of a grid at the hierarchy's current tick.
void RefineAround(Hierarchy& h, uint32_t t, int levels) {
  for (int level = 0; level < levels; ++level)
    h.Refine(h.Locate(t, false, 0.3f, 0.3f, [](const Node&) { return true; }), RefineOptions{});
}

bool Refined(const Hierarchy& h, uint32_t root) { return !h.GetNode(root).IsLeaf(); }

TEST(CollectorTest, OldestGoFirstAndYoungOrKeptStay) {
  const Scene s = GridScene(8);
  Hierarchy h(s);
  SampleCache cache;
  h.SetTick(100);
  RefineAround(h, 2, 2);  // old
  h.SetTick(200);
  RefineAround(h, 100, 2);  // younger
  cache.Reserve(h.VertexCount());
  std::vector<ShadedSample> samples;
  for (VertexId v = 0; v < h.VertexCount(); ++v) samples.push_back({v, Rgb(1.0f), Rgb(1.0f), 0.01f, 16, 0});
  cache.Store(samples);

  CollectorOptions options;
  options.minAgeTicks = 50;
  options.maxGroupsPerStep = 1;
  MemoryCollector collector(options);
  h.SetTick(260);  // the first region is 160 ticks old, the second 60
  collector.Scan(h, cache);
  ASSERT_TRUE(collector.HasCandidates());
  // One group per step: the old region's deepest split goes first.
  CollectStep step = collector.Step(h, cache, ~size_t(0), nullptr);
  EXPECT_EQ(step.groups, 1u);
  EXPECT_GT(step.samplesDropped, 0u);
  EXPECT_TRUE(Refined(h, 100));
  ExpectWholeAndConforming(h, s, "after one step");
  // Keep everything under base triangle 100: the rest goes, 100 stays.
  const auto keep = [&](const Hierarchy::CollapseGroup& g) {
    for (NodeId id : g.nodes)
      if (h.GetNode(id).baseTriangle == 100) return true;
    return false;
  };
  collector = MemoryCollector(CollectorOptions{.minAgeTicks = 50});
  for (int pass = 0; pass < 10; ++pass) {
    collector.Scan(h, cache);
    collector.Step(h, cache, ~size_t(0), keep);
  }
  EXPECT_FALSE(Refined(h, 2));
  EXPECT_TRUE(Refined(h, 100));
  ExpectWholeAndConforming(h, s, "after collecting all but the kept");
  // Freed vertices read as never shaded.
  for (VertexId v = VertexId(h.BaseVertexCount()); v < h.VertexCount(); ++v)
    if (!h.VertexAlive(v)) {
      ASSERT_FALSE(cache.IsShaded(v)) << v;
    }

  // A touch makes a node young again: nothing is collected.
  h.ForEachLeaf(100, [&](NodeId id) { h.Touch(id); });
  collector.Scan(h, cache);
  const CollectStep none = collector.Step(h, cache, ~size_t(0), nullptr);
  EXPECT_EQ(none.groups, 0u);
  EXPECT_TRUE(Refined(h, 100));
}

TEST(CollectorTest, DataInUseFallsAndFreedSlotsAreReused) {
  const Scene s = GridScene(8);
  Hierarchy h(s);
  SampleCache cache;
  for (uint32_t t = 0; t < 128; t += 3) RefineAround(h, t, 3);
  cache.Reserve(h.VertexCount());
  const size_t peakNodes = h.NodeCount(), peakVertices = h.VertexCount();
  const size_t before = MemoryCollector::DataInUse(h, cache, 0);
  h.SetTick(1000);
  MemoryCollector collector(CollectorOptions{.budgetBytes = before, .minAgeTicks = 10});
  EXPECT_TRUE(collector.ShouldStart(before));
  collector.Scan(h, cache);
  const CollectStep step = collector.Step(h, cache, ~size_t(0), nullptr);
  EXPECT_GT(step.groups, 0u);
  const size_t after = MemoryCollector::DataInUse(h, cache, 0);
  EXPECT_LT(after, before);
  EXPECT_GE(before - after, step.bytesFreed / 2);  // the step's own account is close to the measure
  // Everything collected (pass after pass: a scan finds the bottom level),
  // refining the same places again fits in the freed slots.
  for (int pass = 0; pass < 20 && h.LiveNodeCount() > h.RootCount(); ++pass) {
    collector.Scan(h, cache);
    while (collector.HasCandidates()) collector.Step(h, cache, ~size_t(0), nullptr);
  }
  ASSERT_EQ(h.LiveNodeCount(), h.RootCount());
  for (uint32_t t = 0; t < 128; t += 3) RefineAround(h, t, 3);
  EXPECT_LE(h.NodeCount(), peakNodes + 8);
  EXPECT_LE(h.VertexCount(), peakVertices + 8);
  ExpectWholeAndConforming(h, s, "after refining again");
}

TEST(CollectorTest, SceneRecordsAreReleasedAndMadeAgainAsTheyWere) {
  Scene s = GridScene(40);  // 3200 triangles, two-sided: several chunks of roots and base vertices
  s.twoSided = true;
  Hierarchy h(s), fresh(s);
  RefineAround(h, 5, 2);
  for (NodeId r = 0; r < h.RootCount(); ++r) (void)h.GetNode(r);
  for (VertexId v = 0; v < h.BaseVertexCount(); ++v) (void)h.GetVertex(v);
  const size_t before = h.LiveBytes();
  const size_t freed = h.ReleaseSceneRecords();
  EXPECT_GT(freed, 0u);
  EXPECT_EQ(h.LiveBytes(), before - freed);
  // The refined root's chunk stays (its record has children); the others
  // and every base vertex are made again exactly as they were.
  EXPECT_FALSE(h.GetNode(5).IsLeaf());
  for (NodeId r = 0; r < h.RootCount(); ++r) {
    if (r == 5) continue;
    const Node &a = h.GetNode(r), &b = fresh.GetNode(r);
    ASSERT_EQ(a.v, b.v) << r;
    ASSERT_EQ(a.back, b.back) << r;
    ASSERT_EQ(a.baseTriangle, b.baseTriangle) << r;
  }
  for (VertexId v = 0; v < h.BaseVertexCount(); ++v) {
    const SampleVertex &a = h.GetVertex(v), &b = fresh.GetVertex(v);
    ASSERT_EQ(a.position, b.position) << v;
    ASSERT_EQ(a.normal, b.normal) << v;
    ASSERT_EQ(a.point, b.point) << v;
    ASSERT_EQ(a.baseTriangle, b.baseTriangle) << v;
  }
  ExpectWholeAndConforming(h, s, "after releasing the scene's records");
  RefineAround(h, 300, 2);  // refining goes on over released and remade records
  ExpectWholeAndConforming(h, s, "after refining again");
}

// Samples of base vertices go a cache chunk at a time, in age order with
// the subtrees: the oldest first, never a chunk used within the minimum age
// or one a client holds a vertex of (`keepVertices`).
TEST(CollectorTest, BaseVertexSampleChunksAreDroppedOldestFirstUnlessHeld) {
  Scene s = GridScene(40);  // 1681 points, two-sided: 3362 base vertices, chunks 0-2 wholly base
  s.twoSided = true;
  Hierarchy h(s);
  SampleCache cache;
  const auto setTick = [&](uint32_t t) {
    h.SetTick(t);
    cache.SetTick(t);
  };
  setTick(5);
  RefineAround(h, 5, 2);  // older than any sample
  setTick(10);
  cache.Reserve(h.VertexCount());
  std::vector<ShadedSample> samples;
  for (VertexId v = 0; v < h.BaseVertexCount(); ++v) samples.push_back({v, Rgb(1.0f), Rgb(1.0f), 0.01f, 16, 0});
  cache.Store(samples);
  setTick(100);
  constexpr VertexId kChunk = VertexId(SampleCache::kChunkVertices);
  cache.Touch(kChunk + 3);  // chunk 1 was used just now
  constexpr VertexId kHeld = 2 * kChunk + 100;  // a client holds a vertex of chunk 2
  const auto keepVertices = [&](VertexId first, VertexId end) { return first <= kHeld && kHeld < end; };

  MemoryCollector collector(CollectorOptions{.minAgeTicks = 50, .maxGroupsPerStep = 1});
  collector.Scan(h, cache);
  // The refined subtree is older: it goes first.
  CollectStep step = collector.Step(h, cache, ~size_t(0), nullptr, keepVertices);
  EXPECT_EQ(step.groups, 1u);
  EXPECT_EQ(step.chunksDropped, 0u);
  size_t chunks = 0, samplesDropped = 0, kept = 0, bytes = 0;
  const size_t before = MemoryCollector::DataInUse(h, cache, 0);
  while (collector.HasCandidates()) {
    step = collector.Step(h, cache, ~size_t(0), nullptr, keepVertices);
    chunks += step.chunksDropped;
    kept += step.kept;
    if (step.chunksDropped) {
      samplesDropped += step.samplesDropped;
      bytes += step.bytesFreed;
    }
  }
  EXPECT_FALSE(Refined(h, 5));
  EXPECT_EQ(chunks, 1u);  // chunk 0 only
  EXPECT_EQ(kept, 1u);    // chunk 2
  EXPECT_EQ(samplesDropped, size_t(kChunk));
  EXPECT_EQ(bytes, SampleCache::ChunkBytes());
  EXPECT_GE(before - MemoryCollector::DataInUse(h, cache, 0), SampleCache::ChunkBytes() - 512);
  for (VertexId v = 0; v < h.BaseVertexCount(); ++v) ASSERT_EQ(cache.IsShaded(v), v >= kChunk) << v;
  // Asked again, the dropped samples come back (and count as re-shaded).
  cache.Store(std::span(samples).first(kChunk));
  EXPECT_EQ(cache.ReshadedAfterDrop(), size_t(kChunk));
  for (VertexId v = 0; v < h.BaseVertexCount(); ++v) ASSERT_TRUE(cache.IsShaded(v)) << v;
}

}  // namespace
}  // namespace penumbra::sma
