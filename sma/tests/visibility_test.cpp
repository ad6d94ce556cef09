#include "penumbra/sma/visibility.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <map>
#include <random>
#include <tuple>
#include <unordered_map>
#include <vector>

namespace penumbra::sma {
namespace {

// A barycentric distance to an edge this small makes a pixel a tie: float
// (Embree) and double (the reference) arithmetic may each pick either side.
constexpr double kTieBary = 1e-4;

Scene Finish(SceneBuilder& b) {
  Scene s;
  s.twoSided = false;  // one surface per triangle; two-sided hierarchies have tests of their own
  EXPECT_TRUE(b.BuildInto(s).ok());
  return s;
}

// `count` triangles of random size and orientation, centred in [-1, 1]^3,
// facing every which way; optionally inside a closed room, so nothing is background.
Scene FloatingTriangles(uint32_t seed, int count, bool inRoom) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  SceneBuilder b;
  const uint32_t m = b.AddMaterial(Material{});
  for (int i = 0; i < count; ++i) {
    const Vec3 centre(u(rng), u(rng), u(rng));
    const float size = 0.4f + 0.3f * (u(rng) + 1.0f);
    b.AddTriangle({centre + size * Vec3(u(rng), u(rng), u(rng)), centre + size * Vec3(u(rng), u(rng), u(rng)),
                   centre + size * Vec3(u(rng), u(rng), u(rng))},
                  m);
  }
  if (inRoom) {
    const float r = 3.0f;
    for (int axis = 0; axis < 3; ++axis) {
      Vec3 e1(0.0f), e2(0.0f);
      e1[(axis + 1) % 3] = 2.0f * r;
      e2[(axis + 2) % 3] = 2.0f * r;
      for (const float side : {-r, r}) {
        Vec3 corner(-r);
        corner[axis] = side;
        b.AddQuad(corner, e1, e2, m);
      }
    }
  }
  return Finish(b);
}

// A 4x4 grid of unit quads on y = 0 around the origin, with floating
// triangles above it.
Scene FloorAndTriangles() {
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  SceneBuilder b;
  const uint32_t m = b.AddMaterial(Material{});
  for (int i = -2; i < 2; ++i)
    for (int j = -2; j < 2; ++j) b.AddQuad(Vec3(float(i), 0.0f, float(j)), Vec3(0, 0, 1), Vec3(1, 0, 0), m);
  for (int i = 0; i < 6; ++i) {
    const Vec3 c(1.5f * u(rng), 0.6f + 0.4f * u(rng), 1.5f * u(rng));
    b.AddTriangle({c + 0.5f * Vec3(u(rng), u(rng), u(rng)), c + 0.5f * Vec3(u(rng), u(rng), u(rng)),
                   c + 0.5f * Vec3(u(rng), u(rng), u(rng))},
                  m);
  }
  return Finish(b);
}

CameraView View(Vec3 eye, Vec3 target, float fovYDeg, int width, int height) {
  CameraView v;
  v.pose = CameraPose{eye, target, Vec3(0.0f, 1.0f, 0.0f)};
  v.fovYDeg = fovYDeg;
  v.width = width;
  v.height = height;
  EXPECT_TRUE(ValidateCameraView(v).ok());
  return v;
}

std::unique_ptr<VisibilityTracer> TracerFor(const Scene& s) {
  auto tracer = VisibilityTracer::Build(s);
  EXPECT_TRUE(tracer.ok());
  return tracer ? std::move(*tracer) : nullptr;
}

// --- Reference ray casting ----------------------------------------------------

struct ReferenceHit {
  uint32_t triangle = kNoHit;
  double b1 = 0.0, b2 = 0.0;
  bool tie = false;  // within kTieBary of an edge, or level with another hit
};

// Closest hit over every triangle by Möller-Trumbore in double precision,
// both faces; independent of Embree and of the tracer's ray set-up.
ReferenceHit BruteForceHit(const Scene& s, const Vec3& originF, const Vec3& directionF) {
  using D3 = glm::dvec3;
  const D3 o(originF), d(directionF);
  struct Candidate {
    double t, b1, b2, minBary;
    uint32_t triangle;
  };
  std::vector<Candidate> candidates;
  for (uint32_t t = 0; t < s.triangles.size(); ++t) {
    const D3 p0(s.Position(t, 0)), e1 = D3(s.Position(t, 1)) - p0, e2 = D3(s.Position(t, 2)) - p0;
    const D3 pvec = glm::cross(d, e2);
    const double det = glm::dot(e1, pvec);
    if (std::abs(det) < 1e-300) continue;  // seen edge-on
    const D3 tvec = o - p0, qvec = glm::cross(tvec, e1);
    const double b1 = glm::dot(tvec, pvec) / det, b2 = glm::dot(d, qvec) / det;
    const double dist = glm::dot(e2, qvec) / det;
    if (dist > 0.0) candidates.push_back({dist, b1, b2, std::min({1.0 - b1 - b2, b1, b2}), t});
  }
  ReferenceHit hit;
  double closest = std::numeric_limits<double>::infinity();
  for (const Candidate& c : candidates) {
    if (c.minBary >= 0.0 && c.t < closest) {
      closest = c.t;
      hit = {c.triangle, c.b1, c.b2, false};
    }
  }
  // Anything at or in front of the hit (or anywhere, for background) that
  // the ray passes within a hair of could be hit instead.
  for (const Candidate& c : candidates) {
    const bool nearEdge = std::abs(c.minBary) < kTieBary && c.t <= closest * (1.0 + 1e-6);
    const bool levelHit = c.minBary >= 0.0 && c.triangle != hit.triangle && std::abs(c.t - closest) < 1e-6 * closest;
    hit.tie = hit.tie || nearEdge || levelHit;
  }
  return hit;
}

struct Comparison {
  int compared = 0, ties = 0, hits = 0, background = 0;
};

Comparison CompareWithBruteForce(const Scene& s, const CameraView& view, const HitBuffer& traced) {
  EXPECT_EQ(traced.hits.size(), size_t(view.width) * size_t(view.height));
  const PinholeCamera camera(view);
  Comparison c;
  for (int y = 0; y < view.height; ++y) {
    for (int x = 0; x < view.width; ++x) {
      const ReferenceHit ref = BruteForceHit(s, camera.Origin(), camera.DirectionThrough(x + 0.5f, y + 0.5f));
      if (ref.tie) {
        ++c.ties;
        continue;
      }
      ++c.compared;
      const PixelHit& hit = traced.hits[size_t(y) * size_t(view.width) + size_t(x)];
      EXPECT_EQ(hit.triangle, ref.triangle) << "pixel (" << x << ", " << y << ")";
      if (hit.triangle != ref.triangle) continue;
      if (ref.triangle == kNoHit) {
        ++c.background;
        continue;
      }
      ++c.hits;
      EXPECT_NEAR(hit.b1, ref.b1, 1e-4) << "pixel (" << x << ", " << y << ")";
      EXPECT_NEAR(hit.b2, ref.b2, 1e-4) << "pixel (" << x << ", " << y << ")";
    }
  }
  return c;
}

// --- Reference mapping --------------------------------------------------------

bool DescendAlways(const Node&, const void*) { return true; }
bool DescendNever(const Node&, const void*) { return false; }

// A yes or no per node, drawn at random. Nodes are not one array (root
// records are made in chunks on first use), so a node is known by its
// address: Index() maps every node's record to its id once marks are drawn.
struct Marks {
  const Hierarchy* hierarchy;
  std::vector<uint8_t> descend;  // per NodeId
  std::unordered_map<const Node*, NodeId> idOf;
  void Index() {
    idOf.clear();
    for (NodeId id = 0; id < hierarchy->NodeCount(); ++id) idOf.emplace(&hierarchy->GetNode(id), id);
  }
};
bool DescendIfMarked(const Node& n, const void* context) {
  const auto& marks = *static_cast<const Marks*>(context);
  return marks.descend[marks.idOf.at(&n)] != 0;
}

// The smallest barycentric of world point `p` on node `id` (negative
// outside), from the node's corner positions in double precision.
double MinBaryInNode(const Hierarchy& h, NodeId id, const glm::dvec3& p) {
  const Node& n = h.GetNode(id);
  const glm::dvec3 a(h.GetVertex(n.v[0]).position), b(h.GetVertex(n.v[1]).position),
      c(h.GetVertex(n.v[2]).position);
  const glm::dvec3 normal = glm::cross(b - a, c - a);
  const double area2 = glm::dot(normal, normal);
  return std::min({glm::dot(glm::cross(c - b, p - b), normal), glm::dot(glm::cross(a - c, p - c), normal),
                   glm::dot(glm::cross(b - a, p - a), normal)}) /
         area2;
}

struct ReferenceNode {
  NodeId node = kNoNode;
  bool tie = false;  // some level's choice was within a hair of an edge
};

// From the root, while `descend` allows, steps into the child that contains
// the world-space hit point -- geometry, not the barycentric maps.
ReferenceNode BruteForceNode(const Hierarchy& h, const Scene& s, const PixelHit& hit, DescendFunction descend,
                             const void* context) {
  const glm::dvec3 p(s.PointAt(hit.triangle, hit.b1, hit.b2));
  ReferenceNode ref{hit.triangle, false};
  while (!h.GetNode(ref.node).IsLeaf() && descend(h.GetNode(ref.node), context)) {
    const Node& n = h.GetNode(ref.node);
    NodeId best = kNoNode;
    double bestBary = -std::numeric_limits<double>::infinity();
    for (NodeId child = n.firstChild; child < n.firstChild + n.childCount; ++child) {
      const double bary = MinBaryInNode(h, child, p);
      if (bary > bestBary) std::tie(best, bestBary) = std::tuple(child, bary);
    }
    // Children shrink by about half a level: scale the tie zone with them.
    ref.tie = ref.tie || bestBary < std::ldexp(kTieBary, n.depth + 1);
    ref.node = best;
  }
  return ref;
}

// --- VisibilityTracer -----------------------------------------------------------

TEST(VisibilityTracerTest, BuildRejectsAnEmptyScene) {
  const auto tracer = VisibilityTracer::Build(Scene{});
  ASSERT_FALSE(tracer.ok());
  EXPECT_NE(tracer.error().message.find("no triangles"), std::string::npos);
}

// Every pixel against brute force, in open space (background shows) and in a
// closed room (occlusion everywhere), at sizes that do and do not fill whole
// 4x4 packets and 32x32 tiles.
TEST(VisibilityTracerTest, TraceMatchesBruteForce) {
  struct Case {
    bool inRoom;
    CameraView view;
  };
  const Case cases[] = {
      {false, View(Vec3(0.3f, 0.5f, 4.0f), Vec3(0.0f), 45.0f, 64, 48)},
      {false, View(Vec3(-3.0f, 2.0f, -2.0f), Vec3(0.2f, 0.0f, 0.1f), 70.0f, 37, 29)},
      {false, View(Vec3(0.0f, 0.0f, 0.5f), Vec3(0.0f, 0.1f, -1.0f), 120.0f, 66, 35)},  // eye among the triangles
      {true, View(Vec3(2.5f, 1.0f, 2.0f), Vec3(0.0f), 90.0f, 48, 36)},
      {true, View(Vec3(0.1f, -0.2f, 0.0f), Vec3(1.0f, 0.3f, 0.2f), 100.0f, 5, 3)},
  };
  Comparison total;
  for (const Case& c : cases) {
    SCOPED_TRACE(::testing::Message() << (c.inRoom ? "room " : "open ") << c.view.width << "x" << c.view.height);
    const Scene s = FloatingTriangles(11, 40, c.inRoom);
    const auto tracer = TracerFor(s);
    ASSERT_TRUE(tracer);
    HitBuffer traced;
    tracer->Trace(c.view, traced);
    const Comparison r = CompareWithBruteForce(s, c.view, traced);
    if (c.inRoom) {
      EXPECT_EQ(r.background, 0);
    }
    EXPECT_LT(r.ties, (r.compared + r.ties) / 20 + 1);  // ties are the exception
    total.compared += r.compared;
    total.hits += r.hits;
    total.background += r.background;
  }
  // Both outcomes were exercised, on many pixels.
  EXPECT_GT(total.hits, 3000);
  EXPECT_GT(total.background, 1000);
}

// A quad covering exactly the top-left quarter of the field of view (up and
// to the left of the view axis) covers exactly the top-left quarter of the
// pixels: row 0 is the top, column 0 the left.
TEST(VisibilityTracerTest, TopLeftOfTheViewIsTheTopLeftOfTheImage) {
  SceneBuilder b;
  const uint32_t m = b.AddMaterial(Material{});
  // The camera looks down -z from the origin with +y up, so +x is right.
  b.AddQuad(Vec3(-100.0f, 1e-3f, -1.0f), Vec3(100.0f - 1e-3f, 0.0f, 0.0f), Vec3(0.0f, 100.0f, 0.0f), m);
  const Scene s = Finish(b);
  const auto tracer = TracerFor(s);
  ASSERT_TRUE(tracer);
  const CameraView view = View(Vec3(0.0f), Vec3(0.0f, 0.0f, -1.0f), 60.0f, 40, 30);
  HitBuffer traced;
  tracer->Trace(view, traced);
  EXPECT_EQ(traced.view.width, view.width);
  EXPECT_EQ(traced.view.height, view.height);
  for (int y = 0; y < view.height; ++y)
    for (int x = 0; x < view.width; ++x)
      EXPECT_EQ(traced.hits[size_t(y * view.width + x)].triangle != kNoHit, x < view.width / 2 && y < view.height / 2)
          << "pixel (" << x << ", " << y << ")";
}

// --- MapHitsToNodes -----------------------------------------------------------

// A floor and floating triangles, randomly refined, traced from above.
class MapHitsToNodesTest : public ::testing::Test {
 protected:
  MapHitsToNodesTest() : scene_(FloorAndTriangles()), hierarchy_(scene_), tracer_(TracerFor(scene_)) {
    std::mt19937 rng(17);
    for (int step = 0; step < 300; ++step) {
      std::vector<NodeId> leaves;
      hierarchy_.ForEachLeaf(kNoNode, [&](NodeId id) { leaves.push_back(id); });
      hierarchy_.Refine(leaves[rng() % leaves.size()], RefineOptions{});
    }
    marks_.hierarchy = &hierarchy_;
    marks_.descend.resize(hierarchy_.NodeCount());
    for (uint8_t& m : marks_.descend) m = rng() % 4 != 0;
    marks_.Index();
  }

  HitBuffer Trace(int width, int height) const {
    HitBuffer hits;
    tracer_->Trace(View(Vec3(0.2f, 1.6f, 2.4f), Vec3(0.0f, 0.3f, 0.0f), 60.0f, width, height), hits);
    return hits;
  }

  Scene scene_;
  Hierarchy hierarchy_;
  std::unique_ptr<VisibilityTracer> tracer_;
  Marks marks_;
};

TEST_F(MapHitsToNodesTest, MatchesAWorldSpaceDescent) {
  const HitBuffer hits = Trace(96, 72);
  struct Predicate {
    const char* name;
    DescendFunction descend;
    const void* context;
  };
  for (const Predicate& p : {Predicate{"always", DescendAlways, nullptr}, Predicate{"never", DescendNever, nullptr},
                             Predicate{"marked", DescendIfMarked, &marks_}}) {
    SCOPED_TRACE(p.name);
    VisibleSet visible;
    MapHitsToNodes(hierarchy_, hits, p.descend, p.context, visible);
    ASSERT_EQ(visible.pixelNode.size(), hits.hits.size());
    int compared = 0, ties = 0, deepest = 0;
    for (size_t i = 0; i < hits.hits.size(); ++i) {
      const PixelHit& hit = hits.hits[i];
      if (hit.triangle == kNoHit) {
        EXPECT_EQ(visible.pixelNode[i], kNoNode) << "pixel " << i;
        continue;
      }
      const ReferenceNode ref = BruteForceNode(hierarchy_, scene_, hit, p.descend, p.context);
      deepest = std::max(deepest, int(hierarchy_.GetNode(ref.node).depth));
      if (ref.tie) {
        ++ties;
        continue;
      }
      ++compared;
      EXPECT_EQ(visible.pixelNode[i], ref.node) << "pixel " << i;
    }
    EXPECT_GT(compared, 3000);
    EXPECT_LT(ties, compared / 10);
    if (p.descend == DescendNever)
      EXPECT_EQ(deepest, 0);
    else
      EXPECT_GE(deepest, 3);  // the refinement is in view
  }
}

// In a two-sided scene a hit maps into the tree of the side the ray met: the
// back when it travels along the triangle's normal. From under the floor,
// every floor pixel sees the floor's back.
TEST(TwoSidedVisibilityTest, AHitMapsToTheSideTheRayMet) {
  Scene scene = FloorAndTriangles();
  scene.twoSided = true;
  const Hierarchy hierarchy(scene);
  const auto tracer = TracerFor(scene);
  for (const CameraView& view : {View(Vec3(0.2f, 1.6f, 2.4f), Vec3(0.0f, 0.3f, 0.0f), 60.0f, 80, 60),
                                 View(Vec3(0.3f, -1.5f, 0.2f), Vec3(0.0f, 0.0f, -0.1f), 90.0f, 80, 60)}) {
    HitBuffer hits;
    tracer->Trace(view, hits);
    VisibleSet visible;
    MapHitsToNodes(hierarchy, hits, DescendAlways, nullptr, visible);
    const PinholeCamera camera(view);
    const bool underTheFloor = view.pose.eye.y < 0.0f;
    int back = 0, front = 0;
    for (int y = 0; y < view.height; ++y)
      for (int x = 0; x < view.width; ++x) {
        const size_t i = size_t(y) * size_t(view.width) + size_t(x);
        const PixelHit& hit = hits.hits[i];
        if (hit.triangle == kNoHit) continue;
        const float along = glm::dot(camera.DirectionThrough(float(x) + 0.5f, float(y) + 0.5f),
                                     scene.GeometricNormal(hit.triangle));
        if (std::abs(along) > 1e-3f) {
          EXPECT_EQ(hit.backFace, along > 0.0f) << "pixel " << i;
        }
        EXPECT_EQ(hierarchy.IsBack(visible.pixelNode[i]), hit.backFace) << "pixel " << i;
        EXPECT_EQ(hierarchy.GetNode(visible.pixelNode[i]).baseTriangle, hit.triangle);
        (hit.backFace ? back : front) += 1;
        if (underTheFloor && hit.triangle < 32) {
          EXPECT_TRUE(hit.backFace) << "floor pixel " << i;
        }
      }
    EXPECT_GT(underTheFloor ? back : front, 1000);
  }
}

// Static instances (issue 15): copies of one mesh share one Embree BVH, so a
// hit names its copy by instID and the mesh's triangle by primID; the tracer
// must turn the two into the copy's own triangle of Scene::triangles (where
// the copies are stored in world space) and judge the side met with the
// copy's world normal. Every pixel against brute force over all triangles
// of the same scene, with a movable object before the copies in Embree's
// instance numbering, and copies turned (one upside down, so its floor quad
// is seen from behind).
TEST(InstanceVisibilityTest, EachHitNamesItsCopysOwnTriangleAndSide) {
  SceneBuilder meshBuilder;
  {
    std::mt19937 rng(23);
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    const uint32_t m = meshBuilder.AddMaterial(Material{});
    meshBuilder.AddQuad(Vec3(-0.6f, 0.0f, -0.6f), Vec3(0.0f, 0.0f, 1.2f), Vec3(1.2f, 0.0f, 0.0f), m);  // up
    for (int i = 0; i < 8; ++i) {
      const Vec3 c(0.5f * u(rng), 0.3f + 0.2f * u(rng), 0.5f * u(rng));
      meshBuilder.AddTriangle({c + 0.4f * Vec3(u(rng), u(rng), u(rng)), c + 0.4f * Vec3(u(rng), u(rng), u(rng)),
                               c + 0.4f * Vec3(u(rng), u(rng), u(rng))},
                              m);
    }
  }
  Scene mesh = Finish(meshBuilder);
  const uint32_t meshTriangles = uint32_t(mesh.triangles.size());

  SceneBuilder b;
  const uint32_t m = b.AddMaterial(Material{});
  for (int i = -3; i < 3; ++i)  // the scene's own static triangles: a floor
    for (int j = -3; j < 3; ++j) b.AddQuad(Vec3(float(i), 0.0f, float(j)), Vec3(0, 0, 1), Vec3(1, 0, 0), m);
  const RigidTransform places[] = {
      RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.0f, Vec3(-1.4f, 0.05f, 0.0f)),
      RigidTransform::FromAxisAngle(Vec3(0, 1, 0), kPi / 2, Vec3(1.4f, 0.05f, 0.2f)),
      RigidTransform::FromAxisAngle(Vec3(1, 0, 0), kPi, Vec3(0.0f, 1.9f, -1.2f)),  // upside down, in the air
  };
  EXPECT_EQ(b.AddInstances(std::move(mesh), places), 3u * meshTriangles);
  MovableObject crate;  // at its own object space's place, so brute force may read its positions as world ones
  crate.name = "crate";
  b.BeginObject(crate);
  b.AddQuad(Vec3(-0.3f, 0.0f, 1.4f), Vec3(0.6f, 0.0f, 0.0f), Vec3(0.0f, 0.8f, 0.0f), m);
  b.EndObject();
  const Scene scene = Finish(b);
  ASSERT_EQ(scene.instances.size(), 3u);
  ASSERT_EQ(scene.objects.size(), 1u);
  const auto tracer = TracerFor(scene);
  ASSERT_TRUE(tracer);

  // Which copy (0-2), the floor (-1) or the object (3) a triangle belongs to.
  const auto partOf = [&](uint32_t t) {
    for (int k = 0; k < 3; ++k)
      if (t >= scene.instances[k].firstTriangle && t < scene.instances[k].firstTriangle + scene.instances[k].triangleCount)
        return k;
    return t >= scene.objects[0].firstTriangle ? 3 : -1;
  };
  std::map<int, int> pixelsOfPart;
  int backFaces = 0, hitsCompared = 0;
  for (const CameraView& view : {View(Vec3(0.3f, 2.2f, 4.0f), Vec3(0.0f, 0.5f, -0.3f), 50.0f, 128, 80),
                                 View(Vec3(0.4f, 3.4f, 0.3f), Vec3(0.0f, 1.0f, -1.0f), 70.0f, 90, 60)}) {
    SCOPED_TRACE(::testing::Message() << "eye " << view.pose.eye.x << ", " << view.pose.eye.y);
    HitBuffer traced;
    tracer->Trace(view, traced);
    const Comparison r = CompareWithBruteForce(scene, view, traced);
    EXPECT_LT(r.ties, (r.compared + r.ties) / 20 + 1);
    hitsCompared += r.hits;
    const PinholeCamera camera(view);
    for (int y = 0; y < view.height; ++y)
      for (int x = 0; x < view.width; ++x) {
        const PixelHit& hit = traced.hits[size_t(y) * size_t(view.width) + size_t(x)];
        if (hit.triangle == kNoHit) continue;
        ++pixelsOfPart[partOf(hit.triangle)];
        const float along = glm::dot(camera.DirectionThrough(float(x) + 0.5f, float(y) + 0.5f),
                                     scene.GeometricNormal(hit.triangle));
        if (std::abs(along) > 1e-3f) {
          EXPECT_EQ(hit.backFace, along > 0.0f) << "pixel (" << x << ", " << y << ")";
        }
        backFaces += hit.backFace;
      }
  }
  // Every copy, the floor and the object were seen, on many pixels, and
  // some surfaces from behind (the upside-down copy's quad from above).
  EXPECT_GT(hitsCompared, 2000);
  for (int part = -1; part <= 3; ++part) EXPECT_GT(pixelsOfPart[part], 200) << "part " << part;
  EXPECT_GT(backFaces, 100);
}

TEST_F(MapHitsToNodesTest, RefusingToDescendYieldsTheRoots) {
  const HitBuffer hits = Trace(64, 48);
  VisibleSet visible;
  MapHitsToNodes(hierarchy_, hits, DescendNever, nullptr, visible);
  for (size_t i = 0; i < hits.hits.size(); ++i)
    EXPECT_EQ(visible.pixelNode[i], hits.hits[i].triangle == kNoHit ? kNoNode : NodeId(hits.hits[i].triangle));
}

// Agreement with Hierarchy::Locate on every pixel, at a resolution where
// most pixels take MapHitsToNodes' shortcut past the descent.
TEST_F(MapHitsToNodesTest, AgreesExactlyWithLocate) {
  const HitBuffer hits = Trace(400, 300);
  struct CountingMarks {
    const Marks* marks;
    mutable std::atomic<size_t> calls{0};
  } counting{&marks_};
  const DescendFunction countingDescend = [](const Node& n, const void* context) {
    const auto& c = *static_cast<const CountingMarks*>(context);
    c.calls.fetch_add(1, std::memory_order_relaxed);
    return DescendIfMarked(n, c.marks);
  };
  VisibleSet visible;
  MapHitsToNodes(hierarchy_, hits, countingDescend, &counting, visible);
  size_t hitPixels = 0;
  for (size_t i = 0; i < hits.hits.size(); ++i) {
    const PixelHit& hit = hits.hits[i];
    if (hit.triangle == kNoHit) continue;
    ++hitPixels;
    const NodeId located =
        hierarchy_.Locate(hit.triangle, hit.backFace, hit.b1, hit.b2, [&](const Node& n) { return DescendIfMarked(n, &marks_); });
    ASSERT_EQ(visible.pixelNode[i], located) << "pixel " << i;
  }
  EXPECT_LT(counting.calls.load(), hitPixels);  // the shortcut was taken
}

TEST_F(MapHitsToNodesTest, ListsEveryVisibleNodeOnceWithItsPixelCount) {
  const HitBuffer hits = Trace(123, 77);
  VisibleSet visible;
  MapHitsToNodes(hierarchy_, hits, DescendIfMarked, &marks_, visible);
  std::map<NodeId, uint32_t> counted;
  size_t nonBackground = 0;
  for (size_t i = 0; i < hits.hits.size(); ++i) {
    if (visible.pixelNode[i] == kNoNode) continue;
    ++counted[visible.pixelNode[i]];
    ++nonBackground;
  }
  ASSERT_GT(counted.size(), 50u);
  // Refinement made ids of more than one digit of the radix sort (11 bits).
  ASSERT_GT(counted.rbegin()->first, 1u << 11);
  ASSERT_EQ(visible.nodes.size(), counted.size());
  ASSERT_EQ(visible.coverage.size(), counted.size());
  size_t covered = 0;
  size_t k = 0;
  for (const auto& [node, pixels] : counted) {  // in increasing NodeId order
    EXPECT_EQ(visible.nodes[k], node);
    EXPECT_EQ(visible.coverage[k], pixels) << "node " << node;
    covered += visible.coverage[k];
    ++k;
  }
  EXPECT_EQ(covered, nonBackground);
  EXPECT_LT(nonBackground, hits.hits.size());  // some background, which no node covers

  // Reused storage holds no stale entries: a second, unrefined mapping.
  MapHitsToNodes(hierarchy_, hits, DescendNever, nullptr, visible);
  for (NodeId node : visible.nodes) EXPECT_LT(node, scene_.triangles.size());
}

// A refresh re-maps from the applied mapping: after more nodes descend and
// more leaves split (what arriving samples and refinement do between
// collections), it equals a mapping from scratch, pixel for pixel.
TEST_F(MapHitsToNodesTest, ARemapFromThePreviousMappingEqualsOneFromScratch) {
  const HitBuffer hits = Trace(160, 120);
  VisibleSet before;
  MapHitsToNodes(hierarchy_, hits, DescendIfMarked, &marks_, before);
  EXPECT_FALSE(before.sameAsPrevious);
  {  // Nothing changed: the same mapping, and it says so.
    VisibleSet same;
    RemapHitsToNodes(hierarchy_, hits, DescendIfMarked, &marks_, before, same);
    EXPECT_TRUE(same.sameAsPrevious);
    EXPECT_EQ(same.pixelNode, before.pixelNode);
    EXPECT_EQ(same.nodes, before.nodes);
    EXPECT_EQ(same.coverage, before.coverage);
  }
  // Descending only grows: a quarter of the refused nodes now descend, and
  // new splits' nodes descend at random.
  std::mt19937 rng(5);
  for (uint8_t& m : marks_.descend)
    if (!m && rng() % 4 == 0) m = 1;
  for (int step = 0; step < 100; ++step) {
    std::vector<NodeId> leaves;
    hierarchy_.ForEachLeaf(kNoNode, [&](NodeId id) { leaves.push_back(id); });
    hierarchy_.Refine(leaves[rng() % leaves.size()], RefineOptions{});
  }
  const size_t old = marks_.descend.size();
  marks_.descend.resize(hierarchy_.NodeCount());
  for (size_t i = old; i < marks_.descend.size(); ++i) marks_.descend[i] = rng() % 2;
  marks_.Index();
  ASSERT_EQ(before.structureGeneration, hierarchy_.StructureGeneration());  // splits free nothing

  struct CountingMarks {
    const Marks* marks;
    mutable std::atomic<size_t> calls{0};
  };
  const DescendFunction countingDescend = [](const Node& n, const void* context) {
    const auto& c = *static_cast<const CountingMarks*>(context);
    c.calls.fetch_add(1, std::memory_order_relaxed);
    return DescendIfMarked(n, c.marks);
  };
  CountingMarks fromScratchCalls{&marks_}, remapCalls{&marks_};
  VisibleSet fromScratch, remapped;
  MapHitsToNodes(hierarchy_, hits, countingDescend, &fromScratchCalls, fromScratch);
  RemapHitsToNodes(hierarchy_, hits, countingDescend, &remapCalls, before, remapped);
  ASSERT_EQ(remapped.pixelNode, fromScratch.pixelNode);
  EXPECT_FALSE(remapped.sameAsPrevious);
  EXPECT_EQ(remapped.nodes, fromScratch.nodes);
  EXPECT_EQ(remapped.coverage, fromScratch.coverage);
  EXPECT_NE(fromScratch.pixelNode, before.pixelNode);  // the test changed the mapping
  EXPECT_LT(remapCalls.calls.load(), fromScratchCalls.calls.load());  // and the re-map looked at less

  // A mapping made at another structure generation is not used: a full map.
  VisibleSet stale = before;
  stale.structureGeneration += 1;
  VisibleSet again;
  RemapHitsToNodes(hierarchy_, hits, DescendIfMarked, &marks_, stale, again);
  EXPECT_EQ(again.pixelNode, fromScratch.pixelNode);
  EXPECT_FALSE(again.sameAsPrevious);
}

}  // namespace
}  // namespace penumbra::sma
