#include "penumbra/sma/hierarchy.h"

#include <atomic>
#include <map>
#include <random>
#include <set>
#include <thread>

#include <gtest/gtest.h>

#include "hierarchy_test_scenes.h"

namespace penumbra::sma {
namespace {

TEST(HierarchyTest, RootsAndBaseVerticesKeepSceneIndices) {
  const Scene s = GridScene(2);
  Hierarchy h(s);
  ASSERT_EQ(h.NodeCount(), s.triangles.size());
  ASSERT_EQ(h.VertexCount(), s.vertices.size());
  for (NodeId t = 0; t < s.triangles.size(); ++t) {
    EXPECT_EQ(h.GetNode(t).baseTriangle, t);
    EXPECT_EQ(h.GetNode(t).v, s.triangles[t].v);
    EXPECT_TRUE(h.GetNode(t).IsLeaf());
  }
  for (VertexId v = 0; v < s.vertices.size(); ++v) {
    const SampleVertex& sv = h.GetVertex(v);
    EXPECT_EQ(sv.position, s.vertices[v].position);
    // Its base triangle and barycentrics point back at the vertex.
    EXPECT_LT(glm::length(s.PointAt(sv.baseTriangle, sv.bary.x, sv.bary.y) - sv.position), 1e-6f);
  }
}

// Issue 15: root records are made on first use, by const readers too (the
// SMA's views read under the shared state lock). Readers racing to make the
// same chunks all see whole, correct roots; splits after that find them.
// (Meant for ThreadSanitizer too: scripts/test.sh --tsan.)
TEST(HierarchyTest, RootRecordsMadeByConcurrentReadersAreWholeAndShared) {
  const Scene s = GridScene(40);  // 3200 triangles: several chunks of roots
  Hierarchy h(s);
  const size_t bare = h.MemoryBytes();
  std::vector<std::thread> readers;
  std::atomic<int> wrong{0};
  for (int r = 0; r < 4; ++r)
    readers.emplace_back([&, r] {
      for (size_t i = 0; i < s.triangles.size(); ++i) {
        const NodeId t = NodeId((i * 7 + size_t(r) * 811) % s.triangles.size());  // each its own order
        const Node& n = h.GetNode(t);
        if (n.baseTriangle != t || n.v != s.triangles[t].v || !n.IsLeaf() || n.parent != kNoNode) ++wrong;
        if (h.Locate(t, false, 0.25f, 0.25f, [](const Node&) { return true; }) != t) ++wrong;
      }
    });
  for (auto& t : readers) t.join();
  EXPECT_EQ(wrong.load(), 0);
  EXPECT_GT(h.MemoryBytes(), bare + s.triangles.size() * sizeof(Node) / 2);
  // Splits and conformity work on the records the readers made.
  RefineOptions options;
  const RefineResult result = h.Refine(NodeId(100), options);
  EXPECT_FALSE(result.newVertices.empty());
  EXPECT_EQ(h.GetNode(100).childCount, 4);
  EXPECT_TRUE(h.Conforming());
}

TEST(HierarchyTest, IdsAreStableAcrossRefinement) {
  const Scene s = GridScene(4);
  Hierarchy h(s);
  h.Refine(5, RefineOptions{});
  std::vector<Node> nodesBefore;
  std::vector<SampleVertex> verticesBefore;
  for (NodeId i = 0; i < h.NodeCount(); ++i) nodesBefore.push_back(h.GetNode(i));
  for (VertexId i = 0; i < h.VertexCount(); ++i) verticesBefore.push_back(h.GetVertex(i));
  const auto leaves = Leaves(h);
  h.Refine(leaves[leaves.size() / 2], RefineOptions{});
  for (NodeId i = 0; i < nodesBefore.size(); ++i) {
    EXPECT_EQ(h.GetNode(i).v, nodesBefore[i].v) << "node " << i;
    EXPECT_EQ(h.GetNode(i).baseTriangle, nodesBefore[i].baseTriangle);
    EXPECT_EQ(h.GetNode(i).parent, nodesBefore[i].parent);
  }
  for (VertexId i = 0; i < verticesBefore.size(); ++i) EXPECT_EQ(h.GetVertex(i).position, verticesBefore[i].position);
}

TEST(HierarchyTest, SplitMidpointIsSharedAcrossBaseTriangles) {
  const Scene s = GridScene(1);  // one quad: two base triangles sharing the diagonal
  ASSERT_EQ(s.triangles.size(), 2u);
  Hierarchy h(s);
  const RefineResult r = h.Refine(0, RefineOptions{});
  // The neighbour had to be split too (T-vertex on the diagonal otherwise).
  EXPECT_FALSE(h.GetNode(1).IsLeaf());
  EXPECT_EQ(CountTVertices(h), 0u);
  // 3 midpoints for triangle 0; the neighbour adds only what is not shared.
  std::set<VertexId> fromZero(h.GetNode(0).mid.begin(), h.GetNode(0).mid.end());
  std::set<VertexId> fromOne;
  for (VertexId v : h.GetNode(1).mid)
    if (v != kNoVertex) fromOne.insert(v);
  std::vector<VertexId> shared;
  std::set_intersection(fromZero.begin(), fromZero.end(), fromOne.begin(), fromOne.end(), std::back_inserter(shared));
  ASSERT_EQ(shared.size(), 1u);
  EXPECT_EQ(r.newVertices.size(), fromZero.size() + fromOne.size() - 1);
  // The shared midpoint lies halfway along the diagonal.
  const Vec3 p = h.GetVertex(shared[0]).position;
  EXPECT_NEAR(p.x, 0.5f, 1e-6f);
  EXPECT_NEAR(p.z, 0.5f, 1e-6f);
}

TEST(HierarchyTest, RandomRefinementPreservesAreaAndConformity) {
  const Scene s = GridScene(4);
  Hierarchy h(s);
  std::mt19937 rng(7);
  for (int step = 0; step < 60; ++step) {
    const auto leaves = Leaves(h);
    h.Refine(leaves[rng() % leaves.size()], RefineOptions{});
    ASSERT_EQ(CountTVertices(h), 0u) << "after step " << step;
    ASSERT_TRUE(h.Conforming()) << "after step " << step;
  }
  for (NodeId root = 0; root < s.triangles.size(); ++root) {
    double area = 0.0;
    h.ForEachLeaf(root, [&](NodeId id) { area += h.Area(id); });
    EXPECT_NEAR(area, s.Area(root), 1e-5) << "base triangle " << root;
  }
  // Mixed splits happened: some 1 -> 2 and some 1 -> 4.
  int twos = 0, fours = 0;
  for (NodeId i = 0; i < h.NodeCount(); ++i) {
    twos += h.GetNode(i).childCount == 2;
    fours += h.GetNode(i).childCount == 4;
  }
  EXPECT_GT(twos, 0);
  EXPECT_GT(fours, 0);
}

TEST(HierarchyTest, LocateFindsTheLeafContainingThePoint) {
  const Scene s = GridScene(2);
  Hierarchy h(s);
  std::mt19937 rng(3);
  for (int step = 0; step < 30; ++step) {
    const auto leaves = Leaves(h);
    h.Refine(leaves[rng() % leaves.size()], RefineOptions{});
  }
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  for (int i = 0; i < 2000; ++i) {
    const uint32_t t = uint32_t(rng() % s.triangles.size());
    float b1 = u(rng), b2 = u(rng);
    if (b1 + b2 > 1.0f) {
      b1 = 1.0f - b1;
      b2 = 1.0f - b2;
    }
    const NodeId leaf = h.Locate(t, false, b1, b2, [](const Node&) { return true; });
    ASSERT_TRUE(h.GetNode(leaf).IsLeaf());
    EXPECT_EQ(h.GetNode(leaf).baseTriangle, t);
    EXPECT_TRUE(PointInNode(h, leaf, s.PointAt(t, b1, b2))) << "b=(" << b1 << "," << b2 << ")";
  }
}

// Each side of a surface is shaded on its own: a back root per triangle, on
// the same plane, corners reversed, normals negated, points of its own.
TEST(HierarchyTest, TwoSidedSceneHasABackSurfaceOfItsOwn) {
  Scene s = GridScene(3);
  s.twoSided = true;
  Hierarchy h(s);
  const size_t n = s.triangles.size(), nv = s.vertices.size();
  ASSERT_EQ(h.RootCount(), 2 * n);
  ASSERT_EQ(h.NodeCount(), 2 * n);
  ASSERT_EQ(h.VertexCount(), 2 * nv);
  for (uint32_t t = 0; t < n; ++t) {
    const Node& front = h.GetNode(h.RootOf(t, false));
    const Node& back = h.GetNode(h.RootOf(t, true));
    EXPECT_EQ(h.RootOf(t, false), t);
    EXPECT_EQ(h.RootOf(t, true), n + t);
    EXPECT_FALSE(front.back);
    EXPECT_TRUE(back.back);
    EXPECT_EQ(back.baseTriangle, t);
    // Reversed corners: the back's geometric normal is the front's negated.
    const auto normalOf = [&](const Node& node) {
      const Vec3 a = h.GetVertex(node.v[0]).position, b = h.GetVertex(node.v[1]).position,
                 c = h.GetVertex(node.v[2]).position;
      return glm::normalize(glm::cross(b - a, c - a));
    };
    EXPECT_NEAR(glm::dot(normalOf(front), normalOf(back)), -1.0f, 1e-5f);
    for (int c = 0; c < 3; ++c) {
      const SampleVertex& fv = h.GetVertex(front.v[c]);
      EXPECT_LT(front.v[c], nv);
      EXPECT_GE(back.v[c], nv);
      // A back corner is the base triangle's corner with the negated normal,
      // and its base triangle and barycentrics say where it is.
      const SampleVertex& bv = h.GetVertex(back.v[c]);
      EXPECT_EQ(bv.normal, -h.GetVertex(back.v[c] - VertexId(nv)).normal);
      EXPECT_NE(bv.point, fv.point);
      EXPECT_LT(glm::length(s.PointAt(bv.baseTriangle, bv.bary.x, bv.bary.y) - bv.position), 1e-6f);
      EXPECT_LT(glm::length(s.PointAt(t, back.bary[c].x, back.bary[c].y) - bv.position), 1e-6f);
    }
  }
  // Refining the back splits back leaves only, conforming on its own side;
  // Locate on the back side finds back leaves containing the point.
  std::mt19937 rng(3);
  for (int i = 0; i < 12; ++i) {
    std::vector<NodeId> backLeaves;
    h.ForEachLeaf(kNoNode, [&](NodeId id) {
      if (h.IsBack(id)) backLeaves.push_back(id);
    });
    const RefineResult r = h.Refine(backLeaves[rng() % backLeaves.size()], RefineOptions{});
    for (NodeId split : r.split) EXPECT_TRUE(h.IsBack(split));
  }
  for (NodeId t = 0; t < n; ++t) EXPECT_TRUE(h.GetNode(t).IsLeaf()) << "front root " << t << " was split";
  std::uniform_real_distribution<float> u(0.0f, 0.5f);
  for (int i = 0; i < 500; ++i) {
    const uint32_t t = uint32_t(rng() % n);
    const float b1 = u(rng), b2 = u(rng);
    const NodeId leaf = h.Locate(t, true, b1, b2, [](const Node&) { return true; });
    EXPECT_TRUE(h.IsBack(leaf));
    EXPECT_EQ(h.GetNode(leaf).baseTriangle, t);
    EXPECT_TRUE(PointInNode(h, leaf, s.PointAt(t, b1, b2)));
  }
  // No T-vertex on the back surface (the front, unrefined, is another surface).
  size_t tVertices = 0;
  const auto backLeaves = Leaves(h);
  for (NodeId id : backLeaves) {
    if (!h.IsBack(id)) continue;
    const Node& leaf = h.GetNode(id);
    for (int k = 0; k < 3; ++k) {
      const Vec3 a = h.GetVertex(leaf.v[(k + 1) % 3]).position, b = h.GetVertex(leaf.v[(k + 2) % 3]).position;
      for (NodeId other : backLeaves) {
        if (!h.IsBack(other)) continue;
        for (VertexId v : h.GetNode(other).v) {
          const Vec3 p = h.GetVertex(v).position;
          const float along = glm::dot(p - a, b - a) / glm::dot(b - a, b - a);
          if (along > 1e-4f && along < 1.0f - 1e-4f && glm::length(a + along * (b - a) - p) < 1e-5f) ++tVertices;
        }
      }
    }
  }
  EXPECT_EQ(tVertices, 0u);
}

TEST(HierarchyTest, LocateStopsWhereThePredicateSaysSo) {
  const Scene s = GridScene(1);
  Hierarchy h(s);
  h.Refine(0, RefineOptions{});
  // Refuse to descend: the root comes back.
  EXPECT_EQ(h.Locate(0, false, 0.2f, 0.2f, [](const Node&) { return false; }), 0u);
  // Descend one level only.
  const NodeId child = h.Locate(0, false, 0.1f, 0.1f, [](const Node& n) { return n.depth == 0; });
  EXPECT_EQ(h.GetNode(child).depth, 1);
  EXPECT_EQ(h.GetNode(child).parent, 0u);
}

TEST(HierarchyTest, CreaseNeighboursSplitWithTheirOwnMidpoints) {
  const Scene s = CubeScene();
  Hierarchy h(s);
  h.Refine(0, RefineOptions{});
  EXPECT_EQ(CountTVertices(h), 0u);
  // Midpoints on a cube edge exist once per face (each with its face's
  // normal) at the same position.
  std::map<std::tuple<float, float, float>, std::set<VertexId>> byPosition;
  for (VertexId v = VertexId(s.vertices.size()); v < h.VertexCount(); ++v) {
    const Vec3 p = h.GetVertex(v).position;
    byPosition[{p.x, p.y, p.z}].insert(v);
  }
  bool sawCreaseMidpoint = false;
  for (const auto& [pos, ids] : byPosition) {
    if (ids.size() < 2) continue;
    sawCreaseMidpoint = true;
    std::set<uint32_t> points;
    for (VertexId v : ids) points.insert(h.GetVertex(v).point);
    EXPECT_EQ(points.size(), 1u);  // one point identity
    const Vec3 n0 = h.GetVertex(*ids.begin()).normal;
    const Vec3 n1 = h.GetVertex(*ids.rbegin()).normal;
    EXPECT_LT(glm::dot(n0, n1), 0.5f);  // different faces' normals
  }
  EXPECT_TRUE(sawCreaseMidpoint);
}

TEST(HierarchyTest, SlimNeighbourSplitsInTwoAndStopsPropagation) {
  SceneBuilder b;
  Material m;
  const uint32_t mat = b.AddMaterial(m);
  // Triangle 0 is fat; triangle 1 shares its long edge and is slim over it;
  // triangle 2 lies beyond triangle 1's other edge.
  b.AddTriangle({Vec3(0, 0, 0), Vec3(4, 0, 0), Vec3(2, 0, -3)}, mat);
  b.AddTriangle({Vec3(4, 0, 0), Vec3(0, 0, 0), Vec3(2, 0, 0.5f)}, mat);
  b.AddTriangle({Vec3(0, 0, 0), Vec3(-1, 0, 2), Vec3(2, 0, 0.5f)}, mat);
  Scene s;
  s.twoSided = false;  // one surface per triangle; two-sided hierarchies have tests of their own
  ASSERT_TRUE(b.BuildInto(s).ok());
  Hierarchy h(s);
  h.Refine(0, RefineOptions{});
  EXPECT_EQ(h.GetNode(0).childCount, 4);
  EXPECT_EQ(h.GetNode(1).childCount, 2);
  EXPECT_TRUE(h.GetNode(2).IsLeaf());
  EXPECT_EQ(CountTVertices(h), 0u);
}

TEST(HierarchyTest, TallNeighbourSplitsInFourAndPassesItOn) {
  SceneBuilder b;
  Material m;
  const uint32_t mat = b.AddMaterial(m);
  // Triangle 1 is tall over the edge it shares with triangle 0.
  b.AddTriangle({Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0.5f, 0, -1)}, mat);
  b.AddTriangle({Vec3(1, 0, 0), Vec3(0, 0, 0), Vec3(0.5f, 0, 3)}, mat);
  b.AddTriangle({Vec3(0, 0, 0), Vec3(-2, 0, 2), Vec3(0.5f, 0, 3)}, mat);
  Scene s;
  s.twoSided = false;  // one surface per triangle; two-sided hierarchies have tests of their own
  ASSERT_TRUE(b.BuildInto(s).ok());
  Hierarchy h(s);
  h.Refine(0, RefineOptions{});
  EXPECT_EQ(h.GetNode(1).childCount, 4);
  EXPECT_FALSE(h.GetNode(2).IsLeaf());  // reached through triangle 1
  EXPECT_EQ(CountTVertices(h), 0u);
}

TEST(HierarchyTest, NonManifoldEdgeSplitsEveryLeafOnIt) {
  SceneBuilder b;
  Material m;
  const uint32_t mat = b.AddMaterial(m);
  // Three fins around the edge (0,0,0)-(0,1,0), 120 degrees apart.
  for (int i = 0; i < 3; ++i) {
    const float a = float(i) * 2.0f * kPi / 3.0f;
    b.AddTriangle({Vec3(0, 0, 0), Vec3(std::cos(a), 0.5f, std::sin(a)), Vec3(0, 1, 0)}, mat);
  }
  Scene s;
  s.twoSided = false;  // one surface per triangle; two-sided hierarchies have tests of their own
  ASSERT_TRUE(b.BuildInto(s).ok());
  Hierarchy h(s);
  h.Refine(0, RefineOptions{});
  EXPECT_FALSE(h.GetNode(1).IsLeaf());
  EXPECT_FALSE(h.GetNode(2).IsLeaf());
  EXPECT_EQ(CountTVertices(h), 0u);
}

TEST(HierarchyTest, SplitBudgetBoundsPropagationAndKeepsConformity) {
  // Long thin strip: each triangle is tall over the edge it shares with the
  // previous one, so the wave would run the whole strip.
  SceneBuilder b;
  Material m;
  const uint32_t mat = b.AddMaterial(m);
  for (int i = 0; i < 40; ++i) {
    const float x = float(i) * 0.1f;
    b.AddTriangle({Vec3(x, 0, 0), Vec3(x + 0.1f, 0, 0), Vec3(x, 0, -1)}, mat);
    b.AddTriangle({Vec3(x + 0.1f, 0, 0), Vec3(x + 0.1f, 0, -1), Vec3(x, 0, -1)}, mat);
  }
  Scene s;
  s.twoSided = false;  // one surface per triangle; two-sided hierarchies have tests of their own
  ASSERT_TRUE(b.BuildInto(s).ok());
  Hierarchy h(s);
  RefineOptions options;
  options.aspectThreshold = 0.5f;
  options.maxSplits4 = 5;
  h.Refine(0, options);
  int fours = 0;
  for (NodeId i = 0; i < h.NodeCount(); ++i) fours += h.GetNode(i).childCount == 4;
  EXPECT_LE(fours, 5);
  EXPECT_EQ(CountTVertices(h), 0u);
}

TEST(HierarchyTest, MidpointVerticesCanBeShadedOnTheirBaseTriangle) {
  const Scene s = GridScene(2);
  Hierarchy h(s);
  std::mt19937 rng(11);
  for (int step = 0; step < 20; ++step) {
    const auto leaves = Leaves(h);
    h.Refine(leaves[rng() % leaves.size()], RefineOptions{});
  }
  for (VertexId v = 0; v < h.VertexCount(); ++v) {
    const SampleVertex& sv = h.GetVertex(v);
    EXPECT_LT(glm::length(s.PointAt(sv.baseTriangle, sv.bary.x, sv.bary.y) - sv.position), 1e-5f) << v;
    EXPECT_NEAR(glm::length(sv.normal), 1.0f, 1e-5f);
    EXPECT_GE(sv.bary.x, -1e-6f);
    EXPECT_GE(sv.bary.y, -1e-6f);
    EXPECT_LE(sv.bary.x + sv.bary.y, 1.0f + 1e-6f);
  }
}

}  // namespace
}  // namespace penumbra::sma
