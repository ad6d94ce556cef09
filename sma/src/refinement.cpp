#include "penumbra/sma/refinement.h"

#include <algorithm>
#include <cmath>
#include <unordered_set>

#include <fmt/format.h>

namespace penumbra::sma {

RefineOptions ToRefineOptions(const RefinementParams& params) {
  RefineOptions o;
  o.aspectThreshold = params.aspectThreshold;
  // Propagation may go one level past the selection limit to keep the mesh
  // conforming.
  o.maxDepth = uint8_t(std::min<int>(int(RefinementParams::kMaxDepthLimit), params.maxDepth + 1));
  return o;
}

float NormalizedLuminanceDifference(std::span<const float> l, float lMax) {
  return NoiseAwareLuminanceDifference(l, {}, 0.0f, lMax);
}

float NoiseAwareLuminanceDifference(std::span<const float> l, std::span<const float> sigma, float z, float lMax) {
  const size_t n = l.size();
  if (n < 2 || !(lMax > 0.0f)) return 0.0f;
  const bool noisy = z > 0.0f && sigma.size() == n;
  double sum = 0.0;
  for (size_t i = 0; i + 1 < n; ++i)
    for (size_t j = i + 1; j < n; ++j) {
      double d = std::abs(double(l[i]) - double(l[j]));
      if (noisy) d = std::max(0.0, d - double(z) * std::sqrt(double(sigma[i]) * sigma[i] + double(sigma[j]) * sigma[j]));
      sum += d * d;
    }
  const double denominator = double((n * n) / 4) * double(lMax) * double(lMax);
  return float(std::sqrt(sum / denominator));
}

float MidpointDeviation(const SampleCache& cache, const Node& n, VertexLuminance& lum, float z, float lMax) {
  if (n.IsLeaf() || !(lMax > 0.0f)) return 0.0f;
  float deviation = 0.0f;
  for (int k = 0; k < 3; ++k) {  // edge k joins corners k+1 and k+2
    const VertexId m = n.mid[size_t(k)];
    const VertexId a = n.v[size_t((k + 1) % 3)], b = n.v[size_t((k + 2) % 3)];
    if (m == kNoVertex || !cache.IsShaded(m) || !cache.IsShaded(a) || !cache.IsShaded(b)) continue;
    const float interpolated = 0.5f * (lum(a) + lum(b));
    const float sigma = std::sqrt(lum.Sigma(m) * lum.Sigma(m) +
                                  0.25f * (lum.Sigma(a) * lum.Sigma(a) + lum.Sigma(b) * lum.Sigma(b)));
    deviation = std::max(deviation, std::abs(lum(m) - interpolated) - z * sigma);
  }
  return std::max(0.0f, deviation) / lMax;
}

// --- VertexLuminance --------------------------------------------------------

VertexLuminance::VertexLuminance(const Hierarchy& hierarchy, const SampleCache& cache, const ViewLuminance& view,
                                 const DragoParams& params)
    : hierarchy_(hierarchy), cache_(cache), view_(view), params_(params) {}

Rgb VertexLuminance::UntexturedRadiance(const Hierarchy& hierarchy, const SampleCache& cache, VertexId v) {
  const SampleVertex& sv = hierarchy.GetVertex(v);
  const Material& m = hierarchy.GetScene().MaterialOf(sv.baseTriangle);
  return m.emission + m.albedo * cache.Irradiance(v) * kInvPi;
}

const VertexLuminance::Value& VertexLuminance::Get(VertexId v) {
  auto [it, inserted] = memo_.try_emplace(v);
  if (!inserted || !cache_.IsShaded(v)) return it->second;
  const float lw = Luminance(UntexturedRadiance(hierarchy_, cache_, v));
  // The renderer's error on E, as an error on Le + Kd E / pi, then through
  // the tone curve by its slope over +-1 standard error.
  const Material& m = hierarchy_.GetScene().MaterialOf(hierarchy_.GetVertex(v).baseTriangle);
  const float sigmaW = Luminance(m.albedo) * kInvPi * cache_.IrradianceStdErr(v);
  it->second.luminance = DragoDisplayLuminance(lw, view_, params_);
  it->second.sigma = 0.5f * (DragoDisplayLuminance(lw + sigmaW, view_, params_) -
                             DragoDisplayLuminance(std::max(0.0f, lw - sigmaW), view_, params_));
  return it->second;
}

ViewLuminance VertexLuminance::Measure(const Hierarchy& hierarchy, const SampleCache& cache,
                                       std::span<const NodeId> nodes) {
  std::vector<Rgb> radiance;
  std::unordered_set<VertexId> seen;
  for (NodeId id : nodes)
    for (VertexId v : hierarchy.GetNode(id).v)
      if (cache.IsShaded(v) && seen.insert(v).second) radiance.push_back(UntexturedRadiance(hierarchy, cache, v));
  return MeasureLuminance(radiance);
}

// --- Refiner ----------------------------------------------------------------

Refiner::Refiner(RefinementParams params) : params_(params), rng_(params.seed, 0x5eed) {}

void Refiner::Reset(const RefinementParams& params) { *this = Refiner(params); }

bool Refiner::Splittable(const Hierarchy& h, const SampleCache& cache, NodeId id, uint32_t coverage) const {
  const Node& n = h.GetNode(id);
  return n.IsLeaf() && n.depth < params_.maxDepth && float(coverage) >= params_.minPixels && CornersShaded(n, cache);
}

bool VertexInSight(const Hierarchy& h, const HitBuffer& hits, const PinholeCamera& camera, VertexId v) {
  const Scene& scene = h.GetScene();
  if (hits.hits.size() != size_t(camera.Width()) * size_t(camera.Height())) return true;  // no image to look in
  const SampleVertex& sv = h.GetVertex(v);
  // The hierarchy holds a moving object at rest and the view saw it posed:
  // no way to tell here, so it counts as seen (the rule stays out of its way).
  if (scene.ObjectOfTriangle(sv.baseTriangle) != kStaticObject) return true;
  const std::optional<Vec2> pixel = camera.PixelOf(sv.position);
  if (!pixel || !(pixel->x >= 0.0f && pixel->x < float(camera.Width()) && pixel->y >= 0.0f &&
                  pixel->y < float(camera.Height())))
    return false;
  const float distance = glm::length(sv.position - camera.Origin());
  const float depth = glm::dot(sv.position - camera.Origin(), camera.Forward());
  // In front of it means nearer by more than 1 % of its distance and two
  // pixels' size there: a crease's other surface, or the vertex's own
  // surface beside it, is not in front of it.
  const float tolerance = 0.01f * distance + 2.0f * camera.PixelSizeAt(depth);
  const int px = int(pixel->x), py = int(pixel->y);
  for (int y = std::max(0, py - 1); y <= std::min(camera.Height() - 1, py + 1); ++y)
    for (int x = std::max(0, px - 1); x <= std::min(camera.Width() - 1, px + 1); ++x) {
      const PixelHit& hit = hits.hits[size_t(y) * size_t(camera.Width()) + size_t(x)];
      if (hit.triangle == kNoHit || hit.triangle >= scene.triangles.size() ||
          scene.ObjectOfTriangle(hit.triangle) != kStaticObject)
        return true;  // nothing (known) in front of it there
      if (glm::length(scene.PointAt(hit.triangle, hit.b1, hit.b2) - camera.Origin()) > distance - tolerance)
        return true;
    }
  return false;
}

namespace {

uint32_t CoverageOf(const VisibleSet& visible, NodeId id) {
  auto it = std::lower_bound(visible.nodes.begin(), visible.nodes.end(), id);
  if (it == visible.nodes.end() || *it != id) return 0;
  return visible.coverage[size_t(it - visible.nodes.begin())];
}

}  // namespace

std::vector<NodeId> Refiner::Select(const Hierarchy& hierarchy, const SampleCache& cache, const HitBuffer& hits,
                                    const VisibleSet& visible, const DragoParams& toneMapping,
                                    bool samplesOutstanding) {
  if (exhausted_ || params_.criterion == Criterion::kNone) {
    exhausted_ = true;
    return {};
  }
  const ViewLuminance view = VertexLuminance::Measure(hierarchy, cache, visible.nodes);
  VertexLuminance lum(hierarchy, cache, view, toneMapping);
  // L_max: the largest tone-mapped luminance in the view (Drago maps the
  // view's maximum close to 1; measured rather than assumed).
  float lMax = 0.0f;
  for (NodeId id : visible.nodes)
    for (VertexId v : hierarchy.GetNode(id).v) lMax = std::max(lMax, lum(v));
  const size_t pixels = size_t(hits.view.width) * size_t(hits.view.height);

  switch (params_.criterion) {
    case Criterion::kNldOs: {
      auto chosen = SelectObjectSpace(hierarchy, cache, hits, visible, lum, lMax, params_.batch);
      if (chosen.empty() && !samplesOutstanding) exhausted_ = true;
      return chosen;
    }
    case Criterion::kNldIs:
      return SelectImageSpace(hierarchy, cache, hits, visible, lum, lMax, samplesOutstanding);
    case Criterion::kRnd: {
      auto chosen = SelectRandom(hierarchy, cache, visible, size_t(params_.pixelFraction * float(pixels)), params_.batch);
      return chosen;
    }
    case Criterion::kNldOsRnd: {
      if (phase_ == 1) {
        auto chosen = SelectRandom(hierarchy, cache, visible, size_t(params_.pixelFraction * 0.25f * float(pixels)),
                                   params_.batch);
        if (!exhausted_) return chosen;
        // The random pass is spent: NLD_OS follows up on what it found.
        exhausted_ = false;
        phase_ = 2;
        if (!chosen.empty()) return chosen;
      }
      auto chosen = SelectObjectSpace(hierarchy, cache, hits, visible, lum, lMax, params_.batch);
      if (chosen.empty() && !samplesOutstanding) {
        if (phase_ == 0) {
          phase_ = 1;
          return SelectRandom(hierarchy, cache, visible, size_t(params_.pixelFraction * 0.25f * float(pixels)),
                              params_.batch);
        }
        exhausted_ = true;
      }
      return chosen;
    }
    case Criterion::kNone:
      break;
  }
  return {};
}

std::vector<NodeId> Refiner::SelectObjectSpace(const Hierarchy& h, const SampleCache& cache, const HitBuffer& hits,
                                               const VisibleSet& visible, VertexLuminance& lum, float lMax,
                                               size_t limit) {
  const float pixels = float(visible.pixelNode.size());
  const PinholeCamera camera(hits.view);
  const auto noCornerInSight = [&](const Node& n) {
    return std::none_of(n.v.begin(), n.v.end(), [&](VertexId v) { return VertexInSight(h, hits, camera, v); });
  };
  struct Candidate {
    float priority;
    NodeId id;
  };
  std::vector<Candidate> candidates;
  for (size_t i = 0; i < visible.nodes.size(); ++i) {
    const NodeId id = visible.nodes[i];
    const uint32_t coverage = visible.coverage[i];
    if (!Splittable(h, cache, id, coverage)) continue;
    const bool large = float(coverage) > params_.largeFraction * pixels;
    const Node& n = h.GetNode(id);
    const float l[3] = {lum(n.v[0]), lum(n.v[1]), lum(n.v[2])};
    const float sigma[3] = {lum.Sigma(n.v[0]), lum.Sigma(n.v[1]), lum.Sigma(n.v[2])};
    const float s = NoiseAwareLuminanceDifference(l, sigma, params_.noiseZ, lMax);
    // Large leaves first (they may hide anything), then by S, then interior
    // probes (whose S is at most S_req) -- see "Interior probes" in the header.
    if (large) candidates.push_back(Candidate{2.0f + float(coverage) / pixels, id});
    else if (s > params_.sReq) candidates.push_back(Candidate{s, id});
    else if (float(coverage) > params_.probeFraction * pixels &&
             (n.parent == kNoNode ||
              MidpointDeviation(cache, h.GetNode(n.parent), lum, params_.noiseZ, lMax) > params_.sReq ||
              noCornerInSight(n)))
      candidates.push_back(Candidate{s, id});
  }
  const size_t keep = std::min(limit, candidates.size());
  std::partial_sort(candidates.begin(), candidates.begin() + std::ptrdiff_t(keep), candidates.end(),
                    [](const Candidate& a, const Candidate& b) { return a.priority > b.priority || (a.priority == b.priority && a.id < b.id); });
  std::vector<NodeId> chosen;
  chosen.reserve(keep);
  for (size_t i = 0; i < keep; ++i) chosen.push_back(candidates[i].id);
  return chosen;
}

std::vector<NodeId> Refiner::SelectImageSpace(const Hierarchy& h, const SampleCache& cache, const HitBuffer& hits,
                                              const VisibleSet& visible, VertexLuminance& lum, float lMax,
                                              bool samplesOutstanding) {
  const int width = hits.view.width, height = hits.view.height;
  if (!quadrantsSeeded_) {
    quadrants_.push_back(Quadrant{0, 0, width - 1, height - 1, 0});
    quadrantsSeeded_ = true;
  }
  const double budget = double(params_.pixelFraction) * double(width) * double(height);
  // Luminance, and its standard error, interpolated over the displayed leaf
  // under a pixel centre.
  struct Interpolated {
    float luminance = 0.0f;
    float sigma = 0.0f;
  };
  auto luminanceAt = [&](int x, int y) -> Interpolated {
    const size_t p = size_t(y) * size_t(width) + size_t(x);
    const NodeId id = visible.pixelNode[p];
    if (id == kNoNode) return {};
    const Node& n = h.GetNode(id);
    const PixelHit& hit = hits.hits[p];
    // Node-local barycentrics of the hit: solve hit = c0 + l1 (c1 - c0) + l2 (c2 - c0)
    // in the base triangle's barycentric plane.
    const Vec2 p0 = n.bary[0], e1 = n.bary[1] - p0, e2 = n.bary[2] - p0, d = Vec2(hit.b1, hit.b2) - p0;
    const float det = e1.x * e2.y - e1.y * e2.x;
    if (std::abs(det) < 1e-30f) return {lum(n.v[0]), lum.Sigma(n.v[0])};
    const float l1 = (d.x * e2.y - d.y * e2.x) / det;
    const float l2 = (e1.x * d.y - e1.y * d.x) / det;
    const float w[3] = {1.0f - l1 - l2, l1, l2};
    Interpolated out;
    for (int k = 0; k < 3; ++k) {
      out.luminance += w[k] * lum(n.v[k]);
      out.sigma += w[k] * lum.Sigma(n.v[k]);
    }
    return out;
  };
  std::vector<NodeId> chosen;
  std::unordered_set<NodeId> taken;
  size_t expectedSamples = requested_;
  while (nextQuadrant_ < quadrants_.size() && chosen.size() < params_.batch) {
    if (double(expectedSamples) >= budget) {
      exhausted_ = true;
      return chosen;
    }
    // Descend a level only once the splits of the level above are shaded and
    // on screen, so each level judges the image its parent level refined.
    const int level = quadrants_[nextQuadrant_].level;
    if (level > level_ && (samplesOutstanding || !chosen.empty())) return chosen;
    level_ = level;
    const Quadrant q = quadrants_[nextQuadrant_++];
    if (q.x1 - q.x0 < 1 && q.y1 - q.y0 < 1) continue;  // pixel-sized: the recursion ends
    const int mx = (q.x0 + q.x1) / 2, my = (q.y0 + q.y1) / 2;
    const int l = q.level + 1;
    const Quadrant children[4] = {{q.x0, q.y0, mx, my, l},
                                  {std::min(mx + 1, q.x1), q.y0, q.x1, my, l},
                                  {q.x0, std::min(my + 1, q.y1), mx, q.y1, l},
                                  {std::min(mx + 1, q.x1), std::min(my + 1, q.y1), q.x1, q.y1, l}};
    float bestS = -1.0f;
    int best = 0;
    for (int c = 0; c < 4; ++c) {
      const Quadrant& r = children[c];
      const Interpolated at[4] = {luminanceAt(r.x0, r.y0), luminanceAt(r.x1, r.y0), luminanceAt(r.x0, r.y1),
                                  luminanceAt(r.x1, r.y1)};
      const float corners[4] = {at[0].luminance, at[1].luminance, at[2].luminance, at[3].luminance};
      const float sigma[4] = {at[0].sigma, at[1].sigma, at[2].sigma, at[3].sigma};
      const float s = NoiseAwareLuminanceDifference(corners, sigma, params_.noiseZ, lMax);
      if (s > bestS) {
        bestS = s;
        best = c;
      }
      quadrants_.push_back(r);
    }
    if (bestS > params_.sReq) {
      const Quadrant& r = children[best];
      const int cx = (r.x0 + r.x1) / 2, cy = (r.y0 + r.y1) / 2;
      const NodeId id = visible.pixelNode[size_t(cy) * size_t(width) + size_t(cx)];
      if (id != kNoNode && Splittable(h, cache, id, CoverageOf(visible, id)) && taken.insert(id).second) {
        chosen.push_back(id);
        expectedSamples += 3;  // a 1 -> 4 split asks for up to three new vertices
      }
    }
  }
  if (nextQuadrant_ >= quadrants_.size()) exhausted_ = true;
  // Visited quadrants are not needed again; keep the list from growing.
  if (nextQuadrant_ > 4096 && nextQuadrant_ * 2 > quadrants_.size()) {
    quadrants_.erase(quadrants_.begin(), quadrants_.begin() + std::ptrdiff_t(nextQuadrant_));
    nextQuadrant_ = 0;
  }
  return chosen;
}

std::vector<NodeId> Refiner::SelectRandom(const Hierarchy& h, const SampleCache& cache, const VisibleSet& visible,
                                          size_t points, size_t limit) {
  const size_t pixels = visible.pixelNode.size();
  std::vector<NodeId> chosen;
  std::unordered_set<NodeId> taken;
  // One point per selection, R points per step (the paper selects points one
  // by one; a point landing on a leaf already chosen in this step, or on one
  // whose children are still being shaded, is spent like any other).
  const size_t stepEnd = std::min(points, pointsDrawn_ + limit);
  while (pointsDrawn_ < stepEnd && pixels > 0) {
    ++pointsDrawn_;
    const NodeId id = visible.pixelNode[rng_.NextBelow(uint32_t(pixels))];
    if (id == kNoNode || !Splittable(h, cache, id, CoverageOf(visible, id))) continue;
    if (taken.insert(id).second) chosen.push_back(id);
  }
  if (pointsDrawn_ >= points) exhausted_ = true;
  return chosen;
}

}  // namespace penumbra::sma
