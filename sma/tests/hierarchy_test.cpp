#include "penumbra/sma/hierarchy.h"

#include <algorithm>
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

// Issue 15: base vertices are made on first use from the scene and 8 bytes
// per scene vertex; the root edge table holds the front side only. What
// follows checks them against the eager construction they replaced
// (6e7c324), written out here independently.

// A cube (its corners split at the creases: vertices sharing points), then
// an irregular tail: a vertex no triangle uses, one at -0 where another is
// at +0, a degenerate triangle with a vertex twice, and a movable object's
// part whose vertex repeats a static position (a point of its own).
Scene IrregularScene(bool twoSided) {
  Scene s = CubeScene();
  s.twoSided = twoSided;
  const uint32_t first = uint32_t(s.vertices.size());
  s.vertices.push_back(Vertex{Vec3(5, 5, 5), Vec3(0, 1, 0)});        // first: used by no triangle
  s.vertices.push_back(Vertex{Vec3(-0.0f, 2, 0), Vec3(0, 0, 1)});    // first + 1
  s.vertices.push_back(Vertex{Vec3(0.0f, 2, 0), Vec3(0, 0, 1)});     // first + 2: the same point
  s.vertices.push_back(Vertex{Vec3(1, 2, 0), Vec3(0, 0, 1)});        // first + 3
  s.vertices.push_back(Vertex{Vec3(0, 3, 0), Vec3(0, 0, 1)});        // first + 4
  s.triangles.push_back(Triangle{{first + 1, first + 3, first + 4}});
  s.triangles.push_back(Triangle{{first + 2, first + 2, first + 3}});  // degenerate: a vertex twice
  s.triangles.push_back(Triangle{{first + 3, first + 2, first + 4}});
  MovableObject object;
  object.name = "part";
  object.firstVertex = first + 5;
  object.vertexCount = 3;
  object.firstTriangle = uint32_t(s.triangles.size());
  object.triangleCount = 1;
  s.vertices.push_back(Vertex{Vec3(1, 2, 0), Vec3(0, 0, 1)});  // at a static vertex's place
  s.vertices.push_back(Vertex{Vec3(2, 2, 0), Vec3(0, 0, 1)});
  s.vertices.push_back(Vertex{Vec3(1, 3, 0), Vec3(0, 0, 1)});
  s.triangles.push_back(Triangle{{first + 5, first + 6, first + 7}});
  s.objects.push_back(object);
  return s;
}

std::vector<SampleVertex> EagerBaseVertices(const Scene& s) {
  const size_t nv = s.vertices.size();
  std::vector<SampleVertex> out((s.twoSided ? 2 : 1) * nv);
  uint32_t points = 0;
  std::vector<std::pair<Vec3, uint32_t>> seen;  // this part's points so far
  for (size_t i = 0; i < nv; ++i) {
    for (const MovableObject& o : s.objects)
      if (o.firstVertex == i) seen.clear();
    SampleVertex& v = out[i];
    v.position = s.vertices[i].position;
    v.normal = s.vertices[i].normal;
    v.point = points;
    for (const auto& [p, id] : seen)
      if (p == v.position) v.point = id;  // float ==: -0 equals +0
    if (v.point == points) seen.emplace_back(v.position, points++);
  }
  const std::array<Vec2, 3> rootBary = {Vec2(0, 0), Vec2(1, 0), Vec2(0, 1)};
  for (size_t i = 0; i < nv; ++i) {
    for (uint32_t t = 0; t < s.triangles.size(); ++t) {  // the first triangle using it
      bool on = false;
      for (int c = 0; c < 3; ++c)
        if (s.triangles[t].v[c] == i) {
          on = true;
          out[i].bary = rootBary[c];  // the last corner, should it be there twice
        }
      if (on) {
        out[i].baseTriangle = t;
        break;
      }
    }
  }
  if (s.twoSided)
    for (size_t i = 0; i < nv; ++i) {
      out[nv + i] = out[i];
      out[nv + i].normal = -out[i].normal;
      out[nv + i].point += points;
    }
  return out;
}

// The leaves with an edge on the same two points as `leaf`'s edge `edge`, by
// brute force: leaves in id order, once per such edge, `leaf` excluded.
std::vector<NodeId> NeighboursByBruteForce(const Hierarchy& h, NodeId leaf, int edge) {
  const auto pointEdge = [&](NodeId id, int k) {
    const Node& n = h.GetNode(id);
    const uint32_t a = h.GetVertex(n.v[(k + 1) % 3]).point, b = h.GetVertex(n.v[(k + 2) % 3]).point;
    return std::pair(std::min(a, b), std::max(a, b));
  };
  auto leaves = Leaves(h);
  std::sort(leaves.begin(), leaves.end());
  std::vector<NodeId> out;
  for (NodeId id : leaves)
    for (int k = 0; k < 3; ++k)
      if (id != leaf && pointEdge(id, k) == pointEdge(leaf, edge)) out.push_back(id);
  return out;
}

void ExpectNeighboursAsByBruteForce(const Hierarchy& h) {
  for (NodeId id : Leaves(h))
    for (int k = 0; k < 3; ++k) {
      const auto got = h.EdgeNeighbours(id, k);
      EXPECT_EQ(std::vector<NodeId>(got.begin(), got.end()), NeighboursByBruteForce(h, id, k))
          << "leaf " << id << " edge " << k;
    }
}

TEST(HierarchyTest, BaseVerticesAreTheEagerOnesOnBothSides) {
  for (bool twoSided : {false, true}) {
    const Scene s = IrregularScene(twoSided);
    const std::vector<SampleVertex> expected = EagerBaseVertices(s);
    Hierarchy h(s);
    ASSERT_EQ(h.BaseVertexCount(), expected.size());
    ASSERT_EQ(h.VertexCount(), expected.size());
    // Backwards, so the last chunk is made first.
    for (VertexId v = VertexId(expected.size()); v-- > 0;) {
      const SampleVertex& got = h.GetVertex(v);
      EXPECT_EQ(got.position, expected[v].position) << v;
      EXPECT_EQ(got.normal, expected[v].normal) << v;
      EXPECT_EQ(got.point, expected[v].point) << v;
      EXPECT_EQ(got.baseTriangle, expected[v].baseTriangle) << v;
      EXPECT_EQ(got.bary, expected[v].bary) << v;
      EXPECT_EQ(got.depth, 0) << v;
    }
    // The -0/+0 pair shares a point; the object's vertex at a static place does not.
    const VertexId first = VertexId(CubeScene().vertices.size());
    EXPECT_EQ(h.GetVertex(first + 1).point, h.GetVertex(first + 2).point);
    EXPECT_NE(h.GetVertex(first + 3).point, h.GetVertex(first + 5).point);
    ExpectNeighboursAsByBruteForce(h);
    // The degenerate root has the other two roots on its edge (first+2, first+3)
    // twice: on two of its edges.
    const NodeId degenerate = NodeId(s.triangles.size() - 3);
    EXPECT_EQ(h.EdgeNeighbours(degenerate, 0).size(), 2u);
    if (twoSided) {
      const NodeId back = h.RootOf(degenerate - 1, true);
      const auto n = h.EdgeNeighbours(back, 0);
      ASSERT_FALSE(n.empty());
      for (NodeId id : n) EXPECT_TRUE(h.IsBack(id));
    }
    EXPECT_TRUE(h.Conforming());
  }
}

TEST(HierarchyTest, AdjacencyAndConformityHoldOnBothSidesWhileRefining) {
  for (bool twoSided : {false, true}) {
    Scene s = GridScene(3);
    s.twoSided = twoSided;
    Hierarchy h(s);
    ExpectNeighboursAsByBruteForce(h);
    std::mt19937 rng(7);
    for (int step = 0; step < 10; ++step) {
      const auto leaves = Leaves(h);
      h.Refine(leaves[rng() % leaves.size()], RefineOptions{});
      EXPECT_TRUE(h.Conforming());
    }
    ExpectNeighboursAsByBruteForce(h);
  }
  // A split without propagation leaves a T-vertex on the unsplit neighbour
  // root, on either side, and Conforming() sees it.
  for (bool back : {false, true}) {
    Scene s = GridScene(2);
    s.twoSided = true;
    Hierarchy h(s);
    ASSERT_TRUE(h.ApplySplit(h.RootOf(0, back), 4, 0).ok());
    EXPECT_FALSE(h.Conforming()) << (back ? "back" : "front");
  }
}

// Base vertex records made by concurrent readers are whole and shared, and
// memory follows them: none before anything reads them.
TEST(HierarchyTest, BaseVertexRecordsAreMadeOnFirstUseByConcurrentReaders) {
  Scene s = GridScene(40);
  s.twoSided = true;
  const std::vector<SampleVertex> expected = EagerBaseVertices(s);
  ASSERT_GT(expected.size(), 3000u);  // several chunks of 1024
  Hierarchy h(s);
  const size_t bare = h.MemoryBytes();
  EXPECT_LT(bare, expected.size() * sizeof(SampleVertex) / 2);
  // Refining makes a few (the corners of what it splits).
  h.Refine(NodeId(0), RefineOptions{});
  const size_t refined = h.MemoryBytes();
  std::vector<std::thread> readers;
  std::atomic<int> wrong{0};
  for (int r = 0; r < 4; ++r)
    readers.emplace_back([&, r] {
      for (size_t i = 0; i < expected.size(); ++i) {
        const VertexId v = VertexId((i * 7 + size_t(r) * 811) % expected.size());
        const SampleVertex& got = h.GetVertex(v);
        if (got.position != expected[v].position || got.normal != expected[v].normal ||
            got.point != expected[v].point || got.baseTriangle != expected[v].baseTriangle ||
            got.bary != expected[v].bary)
          ++wrong;
      }
    });
  for (auto& t : readers) t.join();
  EXPECT_EQ(wrong.load(), 0);
  EXPECT_GT(refined, bare);
  EXPECT_GE(h.MemoryBytes(), bare + expected.size() * sizeof(SampleVertex));
  // The references stay where they were.
  const SampleVertex* first = &h.GetVertex(0);
  h.Refine(NodeId(500), RefineOptions{});
  EXPECT_EQ(first, &h.GetVertex(0));
  EXPECT_TRUE(h.Conforming());
}

}  // namespace
}  // namespace penumbra::sma
