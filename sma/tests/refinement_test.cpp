#include "penumbra/sma/refinement.h"

#include <cmath>
#include <set>

#include <gtest/gtest.h>

#include "shadow_grid_scene.h"

namespace penumbra::sma {
namespace {

// Shades every unshaded vertex: irradiance 1 left of the shadow edge, 0.01 right of it.
void ShadeHardShadow(const Hierarchy& h, SampleCache& cache, bool uniform = false) {
  std::vector<ShadedSample> samples;
  for (VertexId v = 0; v < h.VertexCount(); ++v) {
    if (cache.IsShaded(v)) continue;
    const float e = uniform || h.GetVertex(v).position.x < kShadowEdgeX ? 1.0f : 0.01f;
    samples.push_back(ShadedSample{v, Rgb(0.5f * e * kInvPi), Rgb(e)});
  }
  cache.Store(samples);
}

struct RefinementFixture {
  Scene scene = GridScene();
  Hierarchy hierarchy{scene};
  SampleCache cache;
  std::unique_ptr<VisibilityTracer> tracer;
  HitBuffer hits;
  VisibleSet visible;

  // `shade`: the hard shadow (or uniform light) on every vertex; false leaves
  // the cache empty for a test's own field.
  explicit RefinementFixture(bool uniform = false, bool shade = true) {
    auto t = VisibilityTracer::Build(scene);
    EXPECT_TRUE(t.ok());
    tracer = std::move(*t);
    // Straight down onto the middle of the grid: no background in the image,
    // so the only image-space edge is the shadow's.
    CameraView view;
    view.pose = CameraPose{Vec3(3, 5, 3), Vec3(3, 0, 3), Vec3(0, 0, -1)};
    view.fovYDeg = 45.0f;
    view.width = view.height = kImage;
    tracer->Trace(view, hits);
    if (shade) ShadeHardShadow(hierarchy, cache, uniform);
    Remap();
  }
  void Remap() {
    MapHitsToNodes(
        hierarchy, hits,
        [](const Node& n, const void* c) {
          for (VertexId m : n.mid)
            if (m != kNoVertex && !static_cast<const SampleCache*>(c)->IsShaded(m)) return false;
          return true;
        },
        &cache, visible);
  }
  std::vector<NodeId> Select(Refiner& r, bool outstanding = false) {
    return r.Select(hierarchy, cache, hits, visible, DragoParams{}, outstanding);
  }
  // Splits the chosen leaves, shades what the splits made, re-maps.
  size_t Apply(const std::vector<NodeId>& chosen, const RefinementParams& p, bool uniform = false) {
    size_t created = 0;
    for (NodeId id : chosen)
      if (hierarchy.GetNode(id).IsLeaf()) created += hierarchy.Refine(id, ToRefineOptions(p)).newVertices.size();
    cache.Reserve(hierarchy.VertexCount());
    ShadeHardShadow(hierarchy, cache, uniform);
    Remap();
    return created;
  }
  bool Straddles(NodeId id) const {
    bool lit = false, dark = false;
    for (VertexId v : hierarchy.GetNode(id).v) (hierarchy.GetVertex(v).position.x < kShadowEdgeX ? lit : dark) = true;
    return lit && dark;
  }
};

TEST(NldMetricTest, MatchesEquationOne) {
  const float three[] = {0.0f, 0.0f, 1.0f};
  // sum of squared differences 2, n^2 div 4 = 2 for n = 3.
  EXPECT_NEAR(NormalizedLuminanceDifference(three, 1.0f), 1.0f, 1e-6f);
  const float four[] = {0.0f, 0.0f, 0.0f, 1.0f};
  // sum 3, n^2 div 4 = 4.
  EXPECT_NEAR(NormalizedLuminanceDifference(four, 1.0f), std::sqrt(0.75f), 1e-6f);
  const float halved[] = {0.0f, 0.0f, 0.5f};
  EXPECT_NEAR(NormalizedLuminanceDifference(halved, 0.5f), 1.0f, 1e-6f);  // normalised by L_max
  const float flat[] = {0.3f, 0.3f, 0.3f};
  EXPECT_EQ(NormalizedLuminanceDifference(flat, 1.0f), 0.0f);
}

TEST(NldMetricTest, NoiseAwareDifferenceDiscountsWhatNoiseExplains) {
  const float l[] = {0.0f, 0.0f, 1.0f};
  const float small[] = {0.01f, 0.01f, 0.01f};
  // z = 0 is the plain metric.
  EXPECT_FLOAT_EQ(NoiseAwareLuminanceDifference(l, small, 0.0f, 1.0f), NormalizedLuminanceDifference(l, 1.0f));
  // Each difference of 1 loses 2 * sqrt(2) * 0.01.
  const double d = 1.0 - 2.0 * std::sqrt(2.0) * 0.01;
  EXPECT_NEAR(NoiseAwareLuminanceDifference(l, small, 2.0f, 1.0f), std::sqrt(2.0 * d * d / 2.0), 1e-6);
  // Differences within the noise count for nothing.
  const float close[] = {0.50f, 0.52f, 0.49f};
  const float noisy[] = {0.05f, 0.05f, 0.05f};
  EXPECT_EQ(NoiseAwareLuminanceDifference(close, noisy, 2.0f, 1.0f), 0.0f);
  EXPECT_GT(NormalizedLuminanceDifference(close, 1.0f), 0.0f);
}

TEST(CriterionTest, ParsesNames) {
  for (const char* name : {"none", "nld_os", "nld_is", "rnd", "nld_os_rnd"}) {
    auto c = ParseCriterion(name);
    ASSERT_TRUE(c.ok()) << name;
    EXPECT_EQ(CriterionName(*c), name);
  }
  EXPECT_FALSE(ParseCriterion("nld").ok());
  RefinementParams p;
  EXPECT_TRUE(p.Validate().ok());
  p.sReq = 2.0f;
  EXPECT_FALSE(p.Validate().ok());
}

TEST(NldOsTest, SplitsExactlyTheLeavesAcrossTheShadowEdge) {
  RefinementFixture f;
  RefinementParams p;
  p.criterion = Criterion::kNldOs;
  p.largeFraction = 1.0f;  // only the metric decides here
  p.probeFraction = 1.0f;
  p.batch = 1000;
  Refiner r(p);
  const auto chosen = f.Select(r);
  ASSERT_FALSE(chosen.empty());
  for (NodeId id : chosen) EXPECT_TRUE(f.Straddles(id)) << "leaf " << id << " is not on the shadow edge";
  // Every straddling leaf large enough to split was chosen.
  for (size_t i = 0; i < f.visible.nodes.size(); ++i) {
    if (f.Straddles(f.visible.nodes[i]) && float(f.visible.coverage[i]) >= p.minPixels) {
      EXPECT_NE(std::find(chosen.begin(), chosen.end(), f.visible.nodes[i]), chosen.end());
    }
  }
}

TEST(NldOsTest, RespectsTheBatchSizeAndTheMinimumArea) {
  RefinementFixture f;
  RefinementParams p;
  p.largeFraction = 1.0f;
  p.probeFraction = 1.0f;  // no interior probes: the corners decide
  p.batch = 2;
  Refiner r(p);
  EXPECT_EQ(f.Select(r).size(), 2u);
  p.minPixels = float(kImage * kImage);  // no leaf is that large
  Refiner small(p);
  EXPECT_TRUE(f.Select(small).empty());
}

TEST(NldOsTest, LargeLeavesAreSplitWhateverTheirMetric) {
  RefinementFixture f(/*uniform=*/true);
  RefinementParams p;
  p.largeFraction = 0.005f;  // each grid triangle covers ~1% of the image
  p.batch = 1000;
  Refiner r(p);
  EXPECT_FALSE(f.Select(r).empty());
  p.largeFraction = 1.0f;
  p.probeFraction = 1.0f;  // no interior probes: the corners decide
  Refiner none(p);
  EXPECT_TRUE(f.Select(none).empty());
}

TEST(NldOsTest, IsDoneOnlyWhenNothingIsOutstanding) {
  RefinementFixture f(/*uniform=*/true);
  RefinementParams p;
  p.largeFraction = 1.0f;
  p.probeFraction = 1.0f;  // no interior probes: the corners decide
  Refiner r(p);
  EXPECT_TRUE(f.Select(r, /*outstanding=*/true).empty());
  EXPECT_FALSE(r.Exhausted());
  EXPECT_TRUE(f.Select(r, /*outstanding=*/false).empty());
  EXPECT_TRUE(r.Exhausted());
}

TEST(NldOsTest, RefinesDownToTheEdgeAndLeavesTheRestAlone) {
  RefinementFixture f;
  RefinementParams p;
  p.largeFraction = 1.0f;
  p.probeFraction = 1.0f;  // no interior probes: the corners decide
  p.minPixels = 6.0f;
  Refiner r(p);
  for (int step = 0; step < 200 && !r.Exhausted(); ++step) f.Apply(f.Select(r), p);
  ASSERT_TRUE(r.Exhausted());
  // Straddling leaves still displayed are small: under the pixel minimum.
  float deepest = 0.0f;
  for (size_t i = 0; i < f.visible.nodes.size(); ++i) {
    const NodeId id = f.visible.nodes[i];
    if (f.Straddles(id)) {
      EXPECT_LT(float(f.visible.coverage[i]), p.minPixels * 2.0f) << id;
    }
    deepest = std::max(deepest, float(f.hierarchy.GetNode(id).depth));
  }
  EXPECT_GE(deepest, 3.0f);
  // Far from the edge (x < 1 or x > 5) the roots were never split.
  for (NodeId root = 0; root < f.scene.triangles.size(); ++root) {
    const Vec3 c = f.scene.PointAt(root, 1.0f / 3, 1.0f / 3);
    if (c.x < 1.0f || c.x > 5.0f) {
      EXPECT_TRUE(f.hierarchy.GetNode(root).IsLeaf()) << root;
    }
  }
}

TEST(NldOsTest, NoiseAwareMetricSplitsTheEdgeAndNotTheNoise) {
  RefinementFixture f;
  // Re-shade with noise: a random relative error of up to 20% on every
  // vertex, reported as such.
  SampleCache noisy;
  Pcg32 rng(9, 9);
  std::vector<ShadedSample> samples;
  for (VertexId v = 0; v < f.hierarchy.VertexCount(); ++v) {
    const float e = (f.hierarchy.GetVertex(v).position.x < kShadowEdgeX ? 1.0f : 0.01f) *
                    (0.8f + 0.4f * rng.NextFloat());
    samples.push_back(ShadedSample{v, Rgb(0.5f * e * kInvPi), Rgb(e), 0.2f * e / std::sqrt(3.0f)});
  }
  noisy.Store(samples);
  RefinementParams p;
  p.largeFraction = 1.0f;
  p.probeFraction = 1.0f;  // no interior probes: the corners decide
  p.batch = 1000;
  p.noiseZ = 0.0f;
  Refiner plain(p);
  const auto plainChoice = plain.Select(f.hierarchy, noisy, f.hits, f.visible, DragoParams{}, false);
  p.noiseZ = 2.0f;
  Refiner aware(p);
  const auto awareChoice = aware.Select(f.hierarchy, noisy, f.hits, f.visible, DragoParams{}, false);
  size_t plainOffEdge = 0;
  for (NodeId id : plainChoice) plainOffEdge += !f.Straddles(id);
  EXPECT_GT(plainOffEdge, 0u) << "the plain metric should be fooled by the noise";
  ASSERT_FALSE(awareChoice.empty());
  for (NodeId id : awareChoice) EXPECT_TRUE(f.Straddles(id)) << "leaf " << id << " is off the edge";
}

// A bump at the circumcentre of a grid cell's diagonal: the corners of the
// cell's two triangles (right isosceles, the diagonal their hypotenuse) are
// all sqrt(0.5) from it and read exactly the background, so corners alone
// never split them; the diagonal's midpoint reads the peak.
constexpr float kBumpRadius = 0.6f;
const Vec3 kBumpCentre(2.5f, 0.0f, 2.5f);  // the middle of cell (2, 2)

float BumpIrradiance(const Vec3& p) {
  const float r = glm::length(p - kBumpCentre) / kBumpRadius;
  return 1.0f + 4.0f * std::max(0.0f, 1.0f - r * r);
}

void ShadeBump(const Hierarchy& h, SampleCache& cache) {
  std::vector<ShadedSample> samples;
  for (VertexId v = 0; v < h.VertexCount(); ++v) {
    if (cache.IsShaded(v)) continue;
    const float e = BumpIrradiance(h.GetVertex(v).position);
    samples.push_back(ShadedSample{v, Rgb(0.5f * e * kInvPi), Rgb(e)});
  }
  cache.Store(samples);
}

// Runs NLD_OS to exhaustion on the bump field (`f` made unshaded).
void RefineBump(RefinementFixture& f, const RefinementParams& p) {
  f.cache.Reserve(f.hierarchy.VertexCount());
  ShadeBump(f.hierarchy, f.cache);
  f.Remap();
  Refiner r(p);
  for (int step = 0; step < 500 && !r.Exhausted(); ++step) {
    for (NodeId id : f.Select(r))
      if (f.hierarchy.GetNode(id).IsLeaf()) f.hierarchy.Refine(id, ToRefineOptions(p));
    f.cache.Reserve(f.hierarchy.VertexCount());
    ShadeBump(f.hierarchy, f.cache);
    f.Remap();
  }
  ASSERT_TRUE(r.Exhausted());
}

TEST(NldOsTest, CornersThatAgreeDoNotHideTheInteriorOfABigLeaf) {
  RefinementParams p;
  p.largeFraction = 1.0f;  // each grid triangle covers ~1.4 % of the image: not "large"
  p.batch = 1000;
  {
    RefinementFixture f(/*uniform=*/false, /*shade=*/false);
    p.probeFraction = 1.0f;  // corners only (the paper's NLD_OS)
    RefineBump(f, p);
    EXPECT_EQ(f.hierarchy.NodeCount(), f.scene.triangles.size()) << "corners alone split nothing";
  }
  RefinementFixture f(/*uniform=*/false, /*shade=*/false);
  p.probeFraction = 1.0f / 1024.0f;  // ~9 pixels of this 96 x 96 image
  RefineBump(f, p);
  // The peak is sampled: some vertex within a tenth of the bump's radius.
  float nearest = 1e9f;
  for (VertexId v = 0; v < f.hierarchy.VertexCount(); ++v)
    nearest = std::min(nearest, glm::length(f.hierarchy.GetVertex(v).position - kBumpCentre));
  EXPECT_LT(nearest, 0.1f * kBumpRadius);
  // Where the field is flat, one probe per root and no deeper: leaves whose
  // three corners are all off the bump are at depth 2 at most (a probe,
  // then the propagation of a neighbour's probe); around the bump the
  // probes went on.
  size_t flatDeep = 0, bumpDeep = 0;
  for (NodeId id : f.visible.nodes) {
    const Node& n = f.hierarchy.GetNode(id);
    bool off = true;
    for (VertexId v : n.v) off = off && glm::length(f.hierarchy.GetVertex(v).position - kBumpCentre) > 2.0f;
    if (off) flatDeep += n.depth > 2;
    else bumpDeep += n.depth > 2;
  }
  EXPECT_EQ(flatDeep, 0u) << bumpDeep;
  EXPECT_GT(bumpDeep, 8u);
}

TEST(NldOsTest, InteriorProbesStopWhereTheMidpointsConfirmTheCorners) {
  // A uniform field: every root is probed (split) once; its midpoints agree
  // with its corners, so nothing is probed below. Deeper nodes only come
  // from the splits' propagation, which keeps the mesh conforming: depth 2
  // at most.
  RefinementFixture f(/*uniform=*/true);
  RefinementParams p;
  p.largeFraction = 1.0f;
  p.batch = 1000;
  p.probeFraction = 1.0f / 1024.0f;  // ~9 pixels of this 96 x 96 image, over minPixels
  std::vector<NodeId> big;  // roots covering well over the probe size
  for (size_t i = 0; i < f.visible.nodes.size(); ++i)
    if (float(f.visible.coverage[i]) > 2.0f * p.probeFraction * float(kImage * kImage)) big.push_back(f.visible.nodes[i]);
  ASSERT_GT(big.size(), 20u);
  Refiner r(p);
  for (int step = 0; step < 100 && !r.Exhausted(); ++step) f.Apply(f.Select(r), p, /*uniform=*/true);
  ASSERT_TRUE(r.Exhausted());
  for (NodeId root : big) EXPECT_FALSE(f.hierarchy.GetNode(root).IsLeaf()) << "root " << root << " was not probed";
  for (NodeId id = 0; id < f.hierarchy.NodeCount(); ++id) EXPECT_LE(f.hierarchy.GetNode(id).depth, 2) << id;
}

// A 4 x 4 floor seen from above through a 0.4 x 0.4 hole in a board at
// y = 0.5: every vertex of the floor is hidden, the floor's middle is lit
// and seen. The hole is inside the centre child of one root's first split
// (away from both of the floor's diagonals and from its edges' midpoints).
struct HiddenCornersFixture {
  static constexpr int kSide = 192;
  Scene scene;
  std::unique_ptr<Hierarchy> hierarchy;
  SampleCache cache;
  HitBuffer hits;
  VisibleSet visible;
  uint32_t floorTriangles = 0;

  HiddenCornersFixture() {
    SceneBuilder b;
    const uint32_t mat = b.AddMaterial(Material{});
    b.AddQuad(Vec3(0, 0, 0), Vec3(0, 0, 4), Vec3(4, 0, 0), mat);  // the floor, facing up
    floorTriangles = 2;
    const float y = 0.5f, x0 = 0.8f, x1 = 1.2f, z0 = 2.2f, z1 = 2.6f;  // the hole
    const auto board = [&](float ax, float az, float bx, float bz) {
      b.AddQuad(Vec3(ax, y, az), Vec3(0, 0, bz - az), Vec3(bx - ax, 0, 0), mat);
    };
    board(-2, -2, 6, z0);  // in front of the hole, across the board
    board(-2, z1, 6, 6);   // behind it
    board(-2, z0, x0, z1);  // left of it
    board(x1, z0, 6, z1);   // right of it
    scene.twoSided = false;
    EXPECT_TRUE(b.BuildInto(scene).ok());
    hierarchy = std::make_unique<Hierarchy>(scene);
    auto tracer = VisibilityTracer::Build(scene);
    EXPECT_TRUE(tracer.ok());
    CameraView view;
    view.pose = CameraPose{Vec3(2, 6, 2), Vec3(2, 0, 2), Vec3(0, 0, -1)};
    view.fovYDeg = 70.0f;
    view.width = view.height = kSide;
    (*tracer)->Trace(view, hits);
  }
  void ShadeUniformly() {
    cache.Reserve(hierarchy->VertexCount());
    std::vector<ShadedSample> samples;
    for (VertexId v = 0; v < hierarchy->VertexCount(); ++v)
      if (!cache.IsShaded(v)) samples.push_back(ShadedSample{v, Rgb(0.5f * kInvPi), Rgb(1.0f), 0.001f});
    cache.Store(samples);
    MapHitsToNodes(
        *hierarchy, hits, [](const Node&, const void*) { return true; }, nullptr, visible);
  }
  PinholeCamera Camera() const { return PinholeCamera(hits.view); }
  std::vector<NodeId> Select(Refiner& r) { return r.Select(*hierarchy, cache, hits, visible, DragoParams{}, false); }
};

TEST(VertexInSightTest, SeesWhatNothingHidesInTheImageOnly) {
  HiddenCornersFixture f;
  const Hierarchy& h = *f.hierarchy;
  const PinholeCamera camera = f.Camera();
  // Every floor vertex is under the board.
  for (uint32_t t = 0; t < f.floorTriangles; ++t)
    for (uint32_t v : f.scene.triangles[t].v) EXPECT_FALSE(VertexInSight(h, f.hits, camera, v)) << v;
  // The hole's corners on the board are seen, and so are the board's
  // vertices in the image; its outer corners (-2, 0.5, -2) ... are out of it.
  size_t seen = 0, outside = 0;
  for (uint32_t t = f.floorTriangles; t < f.scene.triangles.size(); ++t)
    for (uint32_t v : f.scene.triangles[t].v) {
      const Vec3 p = f.scene.vertices[v].position;
      const bool inImage = std::abs(p.x - 2.0f) < 3.5f && std::abs(p.z - 2.0f) < 3.5f;
      EXPECT_EQ(VertexInSight(h, f.hits, camera, v), inImage) << p.x << " " << p.z;
      (inImage ? seen : outside)++;
    }
  EXPECT_GT(seen, 4u);
  EXPECT_GT(outside, 4u);
  // PixelOf inverts DirectionThrough.
  const std::optional<Vec2> pixel = camera.PixelOf(Vec3(1, 0, 2.4f));
  ASSERT_TRUE(pixel.has_value());
  const Vec3 d = camera.DirectionThrough(pixel->x, pixel->y);
  EXPECT_NEAR(glm::length(glm::cross(d, glm::normalize(Vec3(1, 0, 2.4f) - Vec3(2, 6, 2)))), 0.0f, 1e-5f);
  EXPECT_FALSE(camera.PixelOf(Vec3(2, 7, 2)).has_value()) << "behind the camera";
}

TEST(NldOsTest, ALeafWhoseCornersAreAllHiddenIsProbed) {
  // Uniform light: no leaf's corners differ, no split's midpoint is off its
  // edge. Both roots are probed once (roots always are); the child seen
  // through the hole has three hidden corners, which stand for nothing the
  // camera sees: it is probed too, and so on down while a seen leaf has no
  // corner in sight and covers more than the probe size.
  HiddenCornersFixture f;
  f.ShadeUniformly();
  RefinementParams p;
  p.largeFraction = 1.0f;
  p.batch = 1000;
  const auto refine = [&](const RefinementParams& params) {
    Refiner r(params);
    for (int step = 0; step < 100 && !r.Exhausted(); ++step) {
      for (NodeId id : f.Select(r)) f.hierarchy->Refine(id, ToRefineOptions(params));
      f.ShadeUniformly();
    }
    EXPECT_TRUE(r.Exhausted());
  };
  refine(p);
  const PinholeCamera camera = f.Camera();
  size_t seenLeaves = 0;
  for (size_t i = 0; i < f.visible.nodes.size(); ++i) {
    const Node& n = f.hierarchy->GetNode(f.visible.nodes[i]);
    if (n.baseTriangle >= f.floorTriangles) continue;
    ++seenLeaves;
    const bool cornerInSight = std::any_of(n.v.begin(), n.v.end(), [&](VertexId v) {
      return VertexInSight(*f.hierarchy, f.hits, camera, v);
    });
    EXPECT_TRUE(cornerInSight || float(f.visible.coverage[i]) <= p.probeFraction * float(f.hits.hits.size()))
        << "a seen floor leaf of depth " << int(n.depth) << " covering " << f.visible.coverage[i]
        << " pixels has no corner in sight";
    EXPECT_GE(n.depth, 2) << "the hole's leaf was not probed below the roots' first split";
  }
  EXPECT_GT(seenLeaves, 0u);
}

TEST(MidpointDeviationTest, IsTheMidpointsDistanceFromItsEdgesInterpolationBeyondNoise) {
  RefinementFixture f(/*uniform=*/true);
  const NodeId root = 0;
  f.hierarchy.Refine(root, RefineOptions{});
  const Node& n = f.hierarchy.GetNode(root);
  ASSERT_EQ(n.childCount, 4);
  // Corners at E = 1, midpoints at 1 except edge 0's at 3, each +-sigma.
  SampleCache cache;
  cache.Reserve(f.hierarchy.VertexCount());
  std::vector<ShadedSample> samples;
  for (VertexId v = 0; v < f.hierarchy.VertexCount(); ++v) {
    const float e = v == n.mid[0] ? 3.0f : 1.0f;
    samples.push_back(ShadedSample{v, Rgb(0.5f * e * kInvPi), Rgb(e), 0.01f});
  }
  cache.Store(samples);
  // The view's statistics over the children: the midpoint is the brightest.
  std::vector<NodeId> children;
  for (uint32_t c = 0; c < n.childCount; ++c) children.push_back(n.firstChild + c);
  const ViewLuminance view = VertexLuminance::Measure(f.hierarchy, cache, children);
  VertexLuminance lum(f.hierarchy, cache, view, DragoParams{});
  const float lMax = std::max(lum(n.mid[0]), lum(n.v[0]));
  const float plain = MidpointDeviation(cache, n, lum, 0.0f, lMax);
  const float expected = (lum(n.mid[0]) - lum(n.v[1])) / lMax;  // corners equal: interpolation = lum(corner)
  EXPECT_NEAR(plain, expected, 1e-5f);
  EXPECT_GT(plain, 0.1f);
  EXPECT_LT(MidpointDeviation(cache, n, lum, 2.0f, lMax), plain) << "noise discounted";
  EXPECT_EQ(MidpointDeviation(cache, f.hierarchy.GetNode(n.firstChild), lum, 0.0f, lMax), 0.0f) << "a leaf";
}

TEST(RndTest, SpendsItsPixelBudgetAndStops) {
  RefinementFixture f;
  RefinementParams p;
  p.criterion = Criterion::kRnd;
  p.pixelFraction = 0.01f;  // 92 points on a 96x96 image
  p.batch = 1000;
  Refiner r(p);
  size_t chosen = 0;
  for (int step = 0; step < 100 && !r.Exhausted(); ++step) chosen += f.Select(r).size();
  EXPECT_TRUE(r.Exhausted());
  EXPECT_GT(chosen, 0u);
  EXPECT_LE(chosen, size_t(0.01f * kImage * kImage));
}

TEST(NldIsTest, SplitsWhereTheImageChangesAndNowhereOnAFlatImage) {
  {
    RefinementFixture f;
    RefinementParams p;
    p.criterion = Criterion::kNldIs;
    p.batch = 1000;
    Refiner r(p);
    const auto chosen = f.Select(r);
    ASSERT_FALSE(chosen.empty());
    // The chosen leaves lie near the edge: within a grid cell of it.
    for (NodeId id : chosen) {
      const Node& n = f.hierarchy.GetNode(id);
      float minX = 1e9f, maxX = -1e9f;
      for (VertexId v : n.v) {
        minX = std::min(minX, f.hierarchy.GetVertex(v).position.x);
        maxX = std::max(maxX, f.hierarchy.GetVertex(v).position.x);
      }
      EXPECT_LT(minX, kShadowEdgeX + 1.0f);
      EXPECT_GT(maxX, kShadowEdgeX - 1.0f);
    }
  }
  {
    RefinementFixture flat(/*uniform=*/true);
    RefinementParams p;
    p.criterion = Criterion::kNldIs;
    Refiner r(p);
    size_t chosen = 0;
    for (int step = 0; step < 10000 && !r.Exhausted(); ++step) chosen += flat.Select(r).size();
    EXPECT_EQ(chosen, 0u);
    EXPECT_TRUE(r.Exhausted());
  }
}

TEST(NldOsRndTest, RandomPassFindsWorkNldOsAloneDoesNot) {
  RefinementFixture f(/*uniform=*/true);
  RefinementParams p;
  p.criterion = Criterion::kNldOsRnd;
  p.largeFraction = 1.0f;
  p.probeFraction = 1.0f;  // no interior probes: the corners decide
  p.pixelFraction = 0.05f;
  Refiner r(p);
  size_t chosen = 0;
  for (int step = 0; step < 1000 && !r.Exhausted(); ++step) chosen += f.Apply(f.Select(r), p, /*uniform=*/true) > 0;
  EXPECT_GT(chosen, 0u);
  EXPECT_TRUE(r.Exhausted());
}

}  // namespace
}  // namespace penumbra::sma
