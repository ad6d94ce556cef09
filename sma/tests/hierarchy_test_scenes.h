#pragma once
// Small scenes and independent checks shared by the hierarchy's and the
// collector's tests.

#include <cmath>
#include <vector>

#include <gtest/gtest.h>

#include "penumbra/common/scene.h"
#include "penumbra/sma/hierarchy.h"

namespace penumbra::sma {

inline Scene GridScene(int n, float creaseAngle = kDefaultCreaseAngleDeg) {
  // n x n quads on the y = 0 plane, each cut into two right triangles.
  SceneBuilder b(creaseAngle);
  Material m;
  const uint32_t mat = b.AddMaterial(m);
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) b.AddQuad(Vec3(float(i), 0, float(j)), Vec3(0, 0, 1), Vec3(1, 0, 0), mat);
  Scene s;
  s.twoSided = false;  // one surface per triangle; two-sided hierarchies have tests of their own
  EXPECT_TRUE(b.BuildInto(s).ok());
  return s;
}

inline Scene CubeScene() {
  SceneBuilder b;
  Material m;
  const uint32_t mat = b.AddMaterial(m);
  b.AddQuad(Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, 0, 1), mat);
  b.AddQuad(Vec3(0, 1, 0), Vec3(0, 0, 1), Vec3(1, 0, 0), mat);
  b.AddQuad(Vec3(0, 0, 0), Vec3(0, 0, 1), Vec3(0, 1, 0), mat);
  b.AddQuad(Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(0, 0, 1), mat);
  b.AddQuad(Vec3(0, 0, 0), Vec3(0, 1, 0), Vec3(1, 0, 0), mat);
  b.AddQuad(Vec3(0, 0, 1), Vec3(1, 0, 0), Vec3(0, 1, 0), mat);
  Scene s;
  s.twoSided = false;  // one surface per triangle; two-sided hierarchies have tests of their own
  EXPECT_TRUE(b.BuildInto(s).ok());
  return s;
}

inline std::vector<NodeId> Leaves(const Hierarchy& h) {
  std::vector<NodeId> out;
  h.ForEachLeaf(kNoNode, [&](NodeId id) { out.push_back(id); });
  return out;
}

// Independent conformity check: no leaf corner lies strictly inside any leaf
// edge (a T-vertex), tested geometrically on positions.
inline size_t CountTVertices(const Hierarchy& h) {
  const auto leaves = Leaves(h);
  // Corners per side: the two sides of a two-sided scene are separate
  // surfaces at the same positions.
  std::vector<Vec3> corners[2];
  for (NodeId id : leaves)
    for (VertexId v : h.GetNode(id).v) corners[h.IsBack(id)].push_back(h.GetVertex(v).position);
  size_t count = 0;
  for (NodeId id : leaves) {
    const Node& n = h.GetNode(id);
    for (int k = 0; k < 3; ++k) {
      const Vec3 a = h.GetVertex(n.v[(k + 1) % 3]).position;
      const Vec3 b = h.GetVertex(n.v[(k + 2) % 3]).position;
      const Vec3 ab = b - a;
      const float len2 = glm::dot(ab, ab);
      for (const Vec3& p : corners[n.back]) {
        const float t = glm::dot(p - a, ab) / len2;
        if (t <= 1e-4f || t >= 1.0f - 1e-4f) continue;
        const Vec3 closest = a + t * ab;
        if (glm::length(p - closest) < 1e-5f * std::sqrt(len2)) ++count;
      }
    }
  }
  return count;
}

inline bool PointInNode(const Hierarchy& h, NodeId id, const Vec3& p) {
  const Node& n = h.GetNode(id);
  const Vec3 a = h.GetVertex(n.v[0]).position, b = h.GetVertex(n.v[1]).position, c = h.GetVertex(n.v[2]).position;
  const Vec3 nrm = glm::cross(b - a, c - a);
  const float eps = -1e-5f * glm::dot(nrm, nrm);
  return glm::dot(glm::cross(b - a, p - a), nrm) >= eps && glm::dot(glm::cross(c - b, p - b), nrm) >= eps &&
         glm::dot(glm::cross(a - c, p - c), nrm) >= eps;
}

}  // namespace penumbra::sma
