// Refinement on the real scenes in ../shared/scenes keeps the leaf mesh
// conforming after every step: it never adds a T-vertex. (Real meshes carry
// T-junctions of their own; the check counts refinement's kind -- a leaf
// corner at the exact midpoint of another leaf's edge -- and requires that
// count never to grow.)

#include <cstring>
#include <filesystem>
#include <random>
#include <unordered_set>

#include <gtest/gtest.h>

#include "penumbra/common/hash.h"
#include "penumbra/common/scene.h"
#include "penumbra/sma/hierarchy.h"

namespace penumbra::sma {
namespace {

namespace fs = std::filesystem;

struct PositionHash {
  size_t operator()(const Vec3& p) const {
    uint32_t b[3];
    std::memcpy(b, &p, sizeof b);
    return size_t(HashCombine(HashCombine(Mix64(b[0]), b[1]), b[2]));
  }
};

// Leaf edges whose exact midpoint is a corner of some leaf of the same side
// (the two sides of a surface are two meshes on one plane).
size_t CountMidpointTVertices(const Hierarchy& h) {
  std::unordered_set<Vec3, PositionHash> cornersOfSide[2];
  h.ForEachLeaf(kNoNode, [&](NodeId id) {
    for (VertexId v : h.GetNode(id).v) cornersOfSide[h.IsBack(id)].insert(h.GetVertex(v).position + Vec3(0.0f));
  });
  size_t count = 0;
  h.ForEachLeaf(kNoNode, [&](NodeId id) {
    const Node& n = h.GetNode(id);
    const auto& corners = cornersOfSide[h.IsBack(id)];
    for (int k = 0; k < 3; ++k) {
      // The same arithmetic as a midpoint vertex's position.
      const Vec3 m = 0.5f * (h.GetVertex(n.v[(k + 1) % 3]).position + h.GetVertex(n.v[(k + 2) % 3]).position);
      count += corners.contains(m + Vec3(0.0f));
    }
  });
  return count;
}

// The scene files ship in the repository; their meshes are in ../shared.
void RefineAndCheck(const fs::path& sceneFile, const fs::path& sharedMesh) {
  const fs::path mesh = fs::path(PENUMBRA_SOURCE_DIR).parent_path() / "shared" / "scenes" / sharedMesh;
  if (!fs::exists(mesh)) GTEST_SKIP() << mesh << " absent (../shared/scenes is not beside the repository)";
  auto scene = LoadScene(sceneFile);
  ASSERT_TRUE(scene.ok()) << scene.error().message;
  Hierarchy h(*scene);
  const size_t inputTJunctions = CountMidpointTVertices(h);
  std::mt19937 rng(5);
  std::vector<NodeId> recent;
  RefineOptions options;
  for (int step = 0; step < 12; ++step) {
    // Alternate fresh base triangles and children of earlier splits, so the
    // refinement goes deep and crosses many base-triangle boundaries.
    NodeId leaf = NodeId(rng() % h.RootCount());
    if (step % 2 == 1 && !recent.empty()) {
      const Node& parent = h.GetNode(recent[rng() % recent.size()]);
      leaf = parent.firstChild + NodeId(rng() % parent.childCount);
    }
    while (!h.GetNode(leaf).IsLeaf()) leaf = h.GetNode(leaf).firstChild;
    const RefineResult r = h.Refine(leaf, options);
    recent.insert(recent.end(), r.split.begin(), r.split.end());
    ASSERT_LE(CountMidpointTVertices(h), inputTJunctions) << "after step " << step << " of " << sceneFile;
  }
  EXPECT_GT(h.NodeCount(), scene->triangles.size() + 40);
}

TEST(SceneConformityTest, SponzaStaysConforming) {
  RefineAndCheck(fs::path(PENUMBRA_SOURCE_DIR) / "scenes" / "sponza.json", "sponza-dabrovic/sponza.obj");
}

TEST(SceneConformityTest, BreakfastRoomStaysConforming) {
  RefineAndCheck(fs::path(PENUMBRA_SOURCE_DIR) / "scenes" / "breakfast-room.json", "breakfast-room/breakfast-room.obj");
}

}  // namespace
}  // namespace penumbra::sma
